# One image for mesh nodes and the host: the project installed, its kernels compiled at build
# time (`meshnode warmup`; minutes, once per image), so no container compiles while a render
# waits. The cache has a fixed place, whatever user or HOME a container runs with.
#
# Build arguments (docker build --build-arg NAME=VALUE; all optional):
#   BASE    the image to start from: any Debian-like image with Python 3.11+ and its venv
#           module (the standard python image by default; tests/test_compose_up.py uses one
#           made from Debian's packages with debootstrap, python3 and python3-venv)
#   WARMUP  which kernel variants to compile: all (default), none (each container compiles
#           what its render needs, on first use), or variant names as meshnode logs them,
#           comma-separated (e.g. polygons/flat/shadows/refraction/bvh, the last part the
#           structure: bvh, or grid or its storage csr, hash or brute-force; the kernels
#           every variant shares are compiled with them)
#   PIP_INDEX_URL, PIP_EXTRA_INDEX_URL   a package index other than PyPI, if pip needs one
#   PIP_CERT  a CA bundle in the base image for pip to trust (e.g. behind a TLS proxy)
ARG BASE=python:3.11-slim
FROM ${BASE}
ARG PIP_INDEX_URL
ARG PIP_EXTRA_INDEX_URL
ARG PIP_CERT
WORKDIR /app
ENV NUMBA_CACHE_DIR=/opt/meshtrace/kernels
# host.run.localmesh.NODE_ENVIRONMENT: no OpenBLAS threads spinning after numpy loads, no
# huge pages for a node's short-lived ray batches
ENV OPENBLAS_NUM_THREADS=1 NUMPY_MADVISE_HUGEPAGE=0
# The project lives in a virtual environment of its own: the same on the python image and on
# a Debian one (whose system Python refuses pip installs beside its own packages).
ENV PATH=/opt/meshtrace/venv/bin:$PATH
# The user containers run as (uid/gid 10001, as deploy/ expects). Its HOME is /tmp, writable
# in any container, Kubernetes' read-only ones included (an emptyDir there).
RUN groupadd --gid 10001 meshtrace \
    && useradd --uid 10001 --gid 10001 --home-dir /tmp --no-create-home \
       --shell /usr/sbin/nologin meshtrace
# The dependencies first, in a layer of their own: a change to the sources reinstalls only
# the project, not numba and numpy.
COPY pyproject.toml README.md ./
RUN python3 -m venv /opt/meshtrace/venv \
    && python -c "import tomllib; print(*tomllib.load(open('pyproject.toml', 'rb'))['project']['dependencies'], sep='\n')" > /tmp/requirements.txt \
    && pip install --no-cache-dir --disable-pip-version-check -r /tmp/requirements.txt \
    && rm /tmp/requirements.txt
COPY protocols protocols
COPY meshnode meshnode
COPY host host
# Declared here, not above: another choice of variants leaves the layers above cached.
ARG WARMUP=all
# The project, then the kernels WARMUP names, compiled from the installed copy (`python -P`:
# not the sources in /app, whose kernels numba would cache apart and no container loads).
# Everything readable by all; the kernel cache owned by that user too, as numba loads kernels
# only from a folder it may write to (a read-only root filesystem therefore copies it to a
# writable volume first: deploy/nodes.yaml).
RUN pip install --no-cache-dir --disable-pip-version-check --no-deps . \
    && if [ "$WARMUP" = all ]; then meshnode warmup; \
       elif [ "$WARMUP" != none ]; then python -P -c 'import sys; \
         from meshnode.engine.variants import Variant; \
         from meshnode.service.warmup import warmup; \
         variants = [Variant.parse(n) for n in sys.argv[1].split(",")]; \
         print(f"kernels ready in {warmup(variants):.1f} s")' "$WARMUP"; \
       fi \
    && mkdir -p /opt/meshtrace/kernels && chmod -R a+rX /opt/meshtrace \
    && chown -R 10001:10001 /opt/meshtrace/kernels
USER 10001:10001
EXPOSE 7700
CMD ["meshnode", "serve", "--listen", "0.0.0.0:7700"]
