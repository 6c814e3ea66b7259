# ngbet in a container (see docs/container.md). The base is an argument so that the image can be
# built from any Debian-based Python image; it must provide python3 with venv and pip.
#   docker build -t ngbet .                          # the runtime image (the last stage)
#   docker build --target test -t ngbet-test .       # on request: the tests against the installed package
#   docker run --rm -v "$PWD/out:/work/out" ngbet run --out /work/out/run
ARG BASE=python:3.11-slim-bookworm

# ngbet and its dependencies in a virtual environment
FROM ${BASE} AS install
ENV DEBIAN_FRONTEND=noninteractive PYVISTA_OFF_SCREEN=true MPLBACKEND=Agg \
    PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1 PYTHONDONTWRITEBYTECODE=1
# libgfortran5: the OpenBLAS of the ngsolve wheel; libgl1, libxrender1, libxext6, libosmesa6: VTK (pyvista)
# rendering off-screen
RUN apt-get update && apt-get install -y --no-install-recommends libgfortran5 libgl1 libxrender1 libxext6 libosmesa6 \
    && rm -rf /var/lib/apt/lists/*
RUN python3 -m venv /opt/ngbet && useradd --create-home --shell /bin/bash ngbet \
    && mkdir -p /work && chown ngbet:ngbet /work
ENV PATH=/opt/ngbet/bin:$PATH
WORKDIR /src
COPY pyproject.toml README.md LICENSE ./
COPY ngbet ./ngbet
COPY studies ./studies
COPY data ./data
COPY geometry ./geometry
# the build context holds no .git: the version and revision ngbet reports (--version, summary.json)
# are passed in, e.g. --build-arg SETUPTOOLS_SCM_PRETEND_VERSION=0.1.dev0+g$(git rev-parse --short HEAD);
# without it, the fallback version of pyproject.toml and the revision "unknown"
ARG SETUPTOOLS_SCM_PRETEND_VERSION
RUN pip install --upgrade pip && pip install ".[cholmod]" && rm -rf /src/build

# the test suite against the installed package, built only on request (--target test): the tests run
# from a folder without the sources, so `import ngbet` resolves to the venv's site-packages
FROM install AS test
# procps: the fault tests look for leftover worker processes with pgrep
RUN apt-get update && apt-get install -y --no-install-recommends procps && rm -rf /var/lib/apt/lists/* \
    && pip install "/src[test]"
COPY --chown=ngbet:ngbet pyproject.toml /home/ngbet/check/
COPY --chown=ngbet:ngbet tests /home/ngbet/check/tests
COPY --chown=ngbet:ngbet examples /home/ngbet/check/examples
COPY --chown=ngbet:ngbet geometry /home/ngbet/check/geometry
COPY --chown=ngbet:ngbet data /home/ngbet/check/data
COPY --chown=ngbet:ngbet docs /home/ngbet/check/docs
USER ngbet
WORKDIR /home/ngbet/check
RUN python -c "import ngbet, sys; assert '/opt/ngbet/' in ngbet.__file__, ngbet.__file__; print(ngbet.__file__)" \
    && python -m pytest -q -p no:cacheprovider

# the runtime image (the default target): `ngbet` as entry point, /work as working directory
FROM install AS runtime
USER ngbet
WORKDIR /work
# prove the image as docs/container.md uses it: a small scene with its VTU file and force plot, a
# commented scene that reads back, a quick study with its figures (all relative to /work, then removed)
RUN ngbet --version && ngbet run --quiet --out out/run --set discretization.mesh_size_mm=20 \
    && test -s out/run/results.csv && test -s out/run/fields.vtu && test -s out/run/force.png \
    && ngbet scene > my_scene.toml && ngbet run my_scene.toml --quiet --out out/mine \
       --set discretization.mesh_size_mm=20 --set outputs.vtk=false \
    && ngbet study alpha1 --quick --quiet --out out/alpha1 && test -s out/alpha1/report.md \
    && ls out/alpha1/*.png && rm -rf out my_scene.toml
ENTRYPOINT ["ngbet"]
CMD ["run", "--out", "/work/out/run"]
