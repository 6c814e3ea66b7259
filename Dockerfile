# ngbet in a container (see docs/container.md). The base is an argument so that the image can be
# built from any Debian-based Python image; it must provide python3 with venv and pip.
#   docker build -t ngbet .                          # installs ngbet, runs the default scene
#   docker build --target test -t ngbet-test .       # also runs the tests against the installed package
#   docker run --rm -v "$PWD/out:/work/out" ngbet run --out /work/out/run
ARG BASE=python:3.11-slim-bookworm
FROM ${BASE} AS base
ENV DEBIAN_FRONTEND=noninteractive PYVISTA_OFF_SCREEN=true MPLBACKEND=Agg \
    PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1 PYTHONDONTWRITEBYTECODE=1
# libgfortran5: the OpenBLAS of the ngsolve wheel; libgl1, libxrender1, libxext6, libosmesa6: VTK (pyvista)
# rendering off-screen (without OSMesa the maps study crashes in VTK)
RUN apt-get update && apt-get install -y --no-install-recommends libgfortran5 libgl1 libxrender1 libxext6 libosmesa6 \
    && rm -rf /var/lib/apt/lists/*
RUN python3 -m venv /opt/ngbet && useradd --create-home --shell /bin/bash ngbet \
    && mkdir -p /work && chown ngbet:ngbet /work
ENV PATH=/opt/ngbet/bin:$PATH
WORKDIR /src
COPY pyproject.toml README.md LICENSE ./
COPY _build ./_build
COPY ngbet ./ngbet
COPY studies ./studies
# the git revision ngbet reports (--version, summary.json); the build context holds no .git:
#   docker build --build-arg REVISION=$(git rev-parse --short=12 HEAD) .
ARG REVISION=unknown
RUN printf 'REVISION = "%s"\n' "$REVISION" > ngbet/_revision.py \
    && pip install --upgrade pip && pip install ".[viz,cholmod]" && rm -rf /src/build
USER ngbet
WORKDIR /work
# prove the image: the default scene to 56 mm, with its VTU file and its plot
RUN ngbet --version && ngbet run --quiet --out /tmp/ngbet-default \
    && test -s /tmp/ngbet-default/results.csv && test -s /tmp/ngbet-default/fields.vtu \
    && test -s /tmp/ngbet-default/force.png && rm -rf /tmp/ngbet-default
ENTRYPOINT ["ngbet"]
CMD ["run", "--out", "/work/out/run"]

# the test suite against the installed package: the tests run from a folder without the sources,
# so `import ngbet` resolves to the venv's site-packages
FROM base AS test
USER root
# procps: the fault tests look for leftover worker processes with pgrep
RUN apt-get update && apt-get install -y --no-install-recommends procps && rm -rf /var/lib/apt/lists/* \
    && pip install "/src[test]"
COPY --chown=ngbet:ngbet pyproject.toml /home/ngbet/check/
COPY --chown=ngbet:ngbet tests /home/ngbet/check/tests
COPY --chown=ngbet:ngbet examples /home/ngbet/check/examples
COPY --chown=ngbet:ngbet geometry /home/ngbet/check/geometry
COPY --chown=ngbet:ngbet data /home/ngbet/check/data
USER ngbet
WORKDIR /home/ngbet/check
RUN python -c "import ngbet, sys; assert '/opt/ngbet/' in ngbet.__file__, ngbet.__file__; print(ngbet.__file__)" \
    && python -m pytest -q -p no:cacheprovider
