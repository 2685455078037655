"""Use cases: what the API and the worker do, one module per resource, between the routers (HTTP)
and the engine (numerics) and the database (persistence). Each takes validated request schemas,
converts them once to the engine's objects (their ``to_engine``), runs the engine and stores or
returns the results through the response schemas."""
