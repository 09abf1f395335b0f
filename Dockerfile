# One image for mesh nodes and the host: the project installed, every kernel variant compiled
# at build time (`meshnode warmup`; minutes, once per image), so no container compiles while a
# render waits. The cache has a fixed place, whatever user or HOME a container runs with.
FROM python:3.11-slim
WORKDIR /app
ENV NUMBA_CACHE_DIR=/opt/meshtrace/kernels
COPY pyproject.toml README.md ./
COPY protocols protocols
COPY meshnode meshnode
COPY host host
RUN pip install --no-cache-dir . && meshnode warmup && chmod -R a+rX /opt/meshtrace
EXPOSE 7700
CMD ["meshnode", "serve", "--listen", "0.0.0.0:7700"]
