# One image for the server, the worker and the agent (see docker-compose.yml).
FROM python:3.11-slim
RUN apt-get update && apt-get install -y --no-install-recommends git && rm -rf /var/lib/apt/lists/*
RUN pip install --no-cache-dir uv
WORKDIR /app
COPY pyproject.toml uv.lock ./
COPY agent agent
COPY server server
COPY examples examples
RUN uv sync --all-packages --frozen --no-dev
ENV PATH="/app/.venv/bin:$PATH" REDLINE_STORAGE_DIR=/data/storage
ENTRYPOINT ["redline"]
