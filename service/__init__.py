"""The REST service (FastAPI), persistence and the job queue: see issue 4. Not built yet."""
