# spacearm service image: migrates the database, then runs the API and one worker.
# More workers: run more containers on the same database volume with `spacearm worker` as the
# command, e.g. `docker run -v spacearm-data:/data spacearm spacearm worker` (SQLite needs them on
# the same host and volume), or scale a compose service whose command is `spacearm worker`.
FROM python:3.11-slim
# NUMBA_CACHE_DIR: where the engine's compiled kernels are cached (writable by the service user;
# filled at build time below, so containers start in about a second instead of compiling).
ENV PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 \
    SPACEARM_DATABASE_URL=sqlite:////data/spacearm.db \
    SPACEARM_HOST=0.0.0.0 SPACEARM_PORT=8000 \
    NUMBA_CACHE_DIR=/var/cache/spacearm/numba
RUN useradd --create-home --uid 10001 spacearm && mkdir /data && chown spacearm /data \
    && mkdir -p /var/cache/spacearm/numba && chown -R spacearm /var/cache/spacearm
WORKDIR /app
COPY pyproject.toml README.md alembic.ini ./
COPY engine ./engine
COPY service ./service
COPY migrations ./migrations
RUN pip install --no-cache-dir . && rm -rf /root/.cache
USER spacearm
# Compile the kernels into the cache now (about a minute, two processes), from / so that the
# installed package is the one imported (numba keys its cache by the source path); a host with
# another CPU recompiles into the same directory on its first start (`spacearm run` says so).
RUN cd / && spacearm compile
VOLUME ["/data"]
EXPOSE 8000
HEALTHCHECK --interval=30s --timeout=5s --start-period=90s --retries=3 \
    CMD python -c "import os, urllib.request; urllib.request.urlopen('http://127.0.0.1:%s/healthz' % os.environ.get('SPACEARM_PORT', '8000'), timeout=4)"
# `spacearm run`: migrate, then the API and one worker; SIGTERM stops both (the worker gives its job
# back); the container stops (and is restarted) if either exits.
CMD ["spacearm", "run"]
