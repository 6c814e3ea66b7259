# ngbet in a container. The base is an argument so that the image can be built from a local
# Debian (../shared/tools/container-check) as from the public python image.
#   docker build -t ngbet .                       # installs ngbet, runs the default scene
#   docker build --target test -t ngbet-test .    # also runs the test suite
#   docker run --rm -v "$PWD/out:/work/out" ngbet ngbet run --out /work/out/run
ARG BASE=python:3.11-slim-bookworm
FROM ${BASE} AS base
ENV DEBIAN_FRONTEND=noninteractive PYVISTA_OFF_SCREEN=true MPLBACKEND=Agg PIP_NO_CACHE_DIR=1
# libgfortran5: the ngsolve wheel's OpenBLAS; libgl1 & co: VTK (pyvista) even off-screen
RUN apt-get update && apt-get install -y --no-install-recommends \
        python3 python3-venv python3-pip libgfortran5 libgl1 libxrender1 libxext6 libosmesa6 git \
    && rm -rf /var/lib/apt/lists/*
RUN python3 -m venv /opt/ngbet
ENV PATH=/opt/ngbet/bin:$PATH
WORKDIR /work
COPY pyproject.toml README.md ./
COPY ngbet ./ngbet
RUN pip install --upgrade pip && pip install ".[test]"
COPY geometry ./geometry
COPY studies ./studies
COPY tests ./tests
COPY bench ./bench
# prove the image: the default scene to 56 mm
RUN ngbet run --quiet --out /tmp/ngbet-default && test -s /tmp/ngbet-default/results.csv
CMD ["ngbet", "run", "--out", "/work/out/run"]

FROM base AS test
RUN python -m pytest -q
