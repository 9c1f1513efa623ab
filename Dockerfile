# syntax=docker/dockerfile:1
# The ActiveTouch app image: web service + dashboard + viser view, demo mode by default.
#   docker compose up --build          (see docker-compose.yml)
# Everything comes from the repository's pins: uv.lock (Python), frontend/package-lock.json (JS).

# --- the dashboard's JavaScript libraries (no build step: dist files are served as they are) ---
FROM node:20-bookworm-slim AS frontend
WORKDIR /src/frontend
COPY frontend/package.json frontend/package-lock.json ./
RUN npm ci --no-audit --no-fund --loglevel=error

# --- the app -------------------------------------------------------------------------------------
FROM python:3.11-slim-bookworm
ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    UV_LINK_MODE=copy \
    UV_PROJECT_ENVIRONMENT=/opt/venv \
    PATH=/opt/venv/bin:$PATH
RUN pip install --no-cache-dir "uv==0.13.8"
WORKDIR /app
# Dependencies first (cached while only the code changes).
COPY pyproject.toml uv.lock README.md ./
RUN uv sync --frozen --no-dev --no-install-project
COPY core core
COPY hardware hardware
COPY app app
COPY bench bench
COPY migrations migrations
COPY alembic.ini ./
COPY frontend frontend
COPY --from=frontend /src/frontend/node_modules frontend/node_modules
RUN uv sync --frozen --no-dev

# An unprivileged user in "dialout", the group that owns serial devices on Debian/Ubuntu hosts.
RUN useradd --create-home --shell /usr/sbin/nologin --groups dialout activetouch \
    && mkdir -p /data && chown activetouch:activetouch /data
USER activetouch
VOLUME ["/data"]
ENV ACTIVETOUCH_DATABASE_URL=sqlite:////data/activetouch.db
# 8000: dashboard + REST API + the 3D view at /viser/ (viser itself listens on the container's
# loopback, port 8081, and is reached only through the app).
EXPOSE 8000
HEALTHCHECK --interval=15s --timeout=5s --start-period=120s --retries=3 \
    CMD ["python", "-c", "import urllib.request; urllib.request.urlopen('http://127.0.0.1:8000/api/v1/health', timeout=4)"]
CMD ["activetouch", "demo", "--host", "0.0.0.0", "--port", "8000", "--viz-port", "8081", "--no-browser"]
