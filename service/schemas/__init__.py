"""Request and response bodies (pydantic), one module per resource; each request schema converts
itself to the engine's objects and each response schema builds itself from the engine's results."""
