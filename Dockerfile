# One image for mesh nodes and the host: the project installed, every kernel variant compiled
# at build time (`meshnode warmup`; minutes, once per image), so no container compiles while a
# render waits. The cache has a fixed place, whatever user or HOME a container runs with.
FROM python:3.11-slim
WORKDIR /app
ENV NUMBA_CACHE_DIR=/opt/meshtrace/kernels
# The user containers run as (uid/gid 10001, as deploy/ expects). Its HOME is /tmp, writable
# in any container, Kubernetes' read-only ones included (an emptyDir there).
RUN groupadd --gid 10001 meshtrace \
    && useradd --uid 10001 --gid 10001 --home-dir /tmp --no-create-home \
       --shell /usr/sbin/nologin meshtrace
COPY pyproject.toml README.md ./
COPY protocols protocols
COPY meshnode meshnode
COPY host host
# Everything readable by all; the kernel cache owned by that user too, as numba loads kernels
# only from a folder it may write to (a read-only root filesystem therefore copies it to a
# writable volume first: deploy/nodes.yaml).
RUN pip install --no-cache-dir . && meshnode warmup && chmod -R a+rX /opt/meshtrace \
    && chown -R 10001:10001 /opt/meshtrace/kernels
USER 10001:10001
EXPOSE 7700
CMD ["meshnode", "serve", "--listen", "0.0.0.0:7700"]
