"""The cyclic garbage collector around a service process's start-up (``spacearm serve``,
``spacearm worker``): off while it imports and loads the kernels, then its objects frozen and
the collector on again (see docs/service.md, "Garbage collection")."""

from __future__ import annotations

import gc


def pause_collector() -> None:
    """Before the process's imports: no cyclic garbage collection until :func:`resume_collector`.
    The imports and the kernels' loading make some 230,000 objects that live as long as the
    process, and about 1,700 that are cyclic garbage; collecting while they grew walked them four
    times in full, 0.4 of the 1.9 s the API's imports took.

    Only when the kernel cache is complete as the process starts: one started by hand on an
    incomplete cache compiles the kernels itself, which makes millions of objects in cycles that
    would stay until the end of its start-up (a compiling process peaked at 872 MiB without
    collections, 524 with them)."""
    from service.run import kernels_compiled  # the launcher's light check: no engine import

    if kernels_compiled():
        gc.disable()


def resume_collector() -> None:
    """At the end of the start-up: keep the objects it made out of full collections
    (:func:`gc.freeze`) and turn the collector on (if :func:`pause_collector` turned it off). No
    collection first: it would add 0.2 s to the start-up, to free about 1,700 objects (1 MB, of
    230,000), which the freeze keeps."""
    gc.freeze()
    gc.enable()
