"""Infrastructure the use cases and routers stand on: the database, settings, logging, metrics,
security, admission, quota, retention, sessions, storage of arrays and JSON encoding, and HTTP
details. Nothing here knows the engine or a resource's schema."""
