"""The REST service: FastAPI app (``service.app``), persistence (``service.models``,
``migrations/``), the job queue (``service.queue``) and the worker (``service.worker``).
Run it with the ``spacearm`` console script (``service.cli``)."""
