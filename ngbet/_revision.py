"""Written at build time by _build/backend.py."""

REVISION = '07bdb2987a7f-dirty'
