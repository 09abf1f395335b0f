# One image for mesh nodes and the host: the project installed, kernels compiled at build time.
FROM python:3.11-slim
WORKDIR /app
COPY pyproject.toml README.md ./
COPY protocols protocols
COPY meshnode meshnode
COPY host host
RUN pip install --no-cache-dir . && meshnode warmup
EXPOSE 7700
CMD ["meshnode", "serve", "--listen", "0.0.0.0:7700"]
