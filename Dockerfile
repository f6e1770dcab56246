# The service image. torch is pinned to 2.13.0; pass a CPU wheel index as the build argument
# PIP_EXTRA_INDEX_URL to avoid pulling the multi-GB CUDA build.
FROM python:3.11-slim
ARG PIP_EXTRA_INDEX_URL=""
ENV PIP_EXTRA_INDEX_URL=${PIP_EXTRA_INDEX_URL}
WORKDIR /app
COPY pyproject.toml README.md ./
COPY bodyschema bodyschema
COPY simulators simulators
COPY service service
COPY emulators emulators
COPY sim2real sim2real
COPY bench bench
COPY cli cli
COPY migrations migrations
RUN pip install --no-cache-dir .
# Run as an unprivileged user; the SQLite default store (./var) is writable by it.
RUN useradd --create-home --uid 10001 bodyhealth && mkdir -p /app/var && chown bodyhealth /app/var
USER bodyhealth
EXPOSE 8000
# Listening on 0.0.0.0 needs BODYHEALTH_API_TOKEN (or BODYHEALTH_API_TOKEN_FILE): docker run -e ...
CMD ["bodyhealth", "serve", "--demo", "--host", "0.0.0.0", "--port", "8000"]
