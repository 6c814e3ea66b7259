"""Shared test helpers, and the test tiers.

Three tiers: the default run (``python -m pytest``) holds the unit and finite-element tests, fast;
``-m integration`` the whole commands, studies, fault injection, builds and the hard cases (the
modules in INTEGRATION_MODULES are marked whole, others mark single tests); ``-m slow`` the long
runs. ``-m "integration or slow"`` with the default gives everything.
"""

import pytest

from ngbet.scene import Scene

#: modules that run whole commands, studies, worker processes and the hard cases
INTEGRATION_MODULES = {"test_command.py", "test_faults.py", "test_hard_cases.py", "test_studies.py",
                       "test_study_workers.py"}


def pytest_collection_modifyitems(config, items):
    for item in items:
        if item.path.name in INTEGRATION_MODULES:
            item.add_marker(pytest.mark.integration)


def coarse(**changes) -> Scene:
    """The paper's scene on a coarse mesh (10 mm, p = 2): seconds, not minutes."""
    base = {"discretization.mesh_size_mm": 10.0, "outputs.vtk": False, "outputs.plot": False}
    base.update(changes)
    return Scene().with_changes(**base)


@pytest.fixture
def coarse_scene():
    return coarse
