"""The one decorator every compiled function uses, and where numba caches the machine code
(:mod:`engine.kernels.cache`)."""

from __future__ import annotations

import contextlib
import ctypes
import functools
import importlib
import mmap
import os
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numba
from llvmlite import binding as llvm
from numba import njit
from numba.core.extending import intrinsic

from engine.kernels.cache import cache_dir, source_hash

__all__ = ["CACHE_DIR", "kernel", "park_linking_modules", "source_hash", "unlinked"]

CACHE_DIR = cache_dir()
numba.config.CACHE_DIR = str(CACHE_DIR)  # type: ignore[attr-defined]  # read by each kernel's cache when decorated
# LLVM at -O1 unless NUMBA_OPT says otherwise: it compiles the kernels in about 15 % less time than
# numba's default -O3 and they run as fast (the paper plan and a batch of 64, measured alike).
# The compiler re-reads NUMBA_* variables before each compilation, so this holds even when numba
# was imported first.
os.environ.setdefault("NUMBA_OPT", "1")


#: Every kernel's dispatcher, in the order they were defined.
KERNELS: list[Any] = []


def kernel(fn: Callable[..., Any] | None = None, *, inline: bool = False) -> Any:
    """``numba.njit`` with the on-disk cache, the GIL released and numpy's error model (a numba
    dispatcher: typed ``Any``, its signature is whatever numba compiles it for).

    ``@kernel(inline=True)``: a kernel with one caller in the engine's compiled code, which numba
    inlines there (its IR, typed in the caller), instead of compiling it alone and linking it in.
    numba runs LLVM's optimisation and code generation on every compiled function together with
    all it links, so each level of calls pays again for the levels below it; an inlined level
    does not (nor does a large callee called by symbol, :func:`unlinked`). Called from Python
    (tests), it compiles alone as any kernel. Only small functions: numba copies an inlined
    function's IR block by block, each block's copy with the whole scope, so the cost grows as
    blocks times variables (the step loop's body, 300 blocks and 3,300 variables, took 4.4 s of a
    cold compilation when it was an inlined kernel of its own)."""
    if fn is None:
        return functools.partial(kernel, inline=inline)
    dispatcher = njit(cache=True, nogil=True, error_model="numpy", inline="always" if inline else "never")(fn)
    dispatcher.add_overload = functools.partial(_add_overload, dispatcher.add_overload)  # type: ignore[method-assign]
    KERNELS.append(dispatcher)
    return dispatcher


def _add_overload(add: Callable[[Any], None], result: Any) -> None:
    """numba's ``Dispatcher.add_overload``, with the library of a kernel loaded from the cache given
    back its ``reload_init`` (numba keeps it on the compile result only): a caller compiled later
    links the library and inherits the library's, so it carries the loaders of the
    :func:`unlinked` callees it calls through that library."""
    if result.reload_init:
        result.library._reload_init.update(result.reload_init)
    add(result)


@dataclass(frozen=True)
class _LoadCallee:
    """Load (or compile) ``module.name`` for ``argtypes`` and make ``symbol`` name it: run by numba
    before it loads from the cache a kernel that calls that one :func:`unlinked` (pickled with the
    kernel, numba's ``reload_init``), so that the call is linked to the callee's machine code (else
    it jumps to nothing). A callee compiled again (another process of ``spacearm compile`` wrote
    the cache's copy last, or its cache entry was lost) has a symbol of its own, since numba's
    symbols carry a number counted per process: ``symbol`` is then added to LLVM's symbols."""

    module: str
    name: str
    argtypes: tuple[Any, ...]
    restype: Any
    symbol: str

    def __call__(self) -> None:
        dispatcher = getattr(importlib.import_module(self.module), self.name)
        dispatcher.compile(self.argtypes)
        result = dispatcher.overloads[self.argtypes]
        if result.signature.return_type != self.restype:
            raise RuntimeError(
                f"{self.module}.{self.name}{self.argtypes} returns {result.signature.return_type}, its caller in the "
                f"kernel cache expects {self.restype}: delete the kernel cache ({CACHE_DIR})"
            )
        if result.fndesc.mangled_name != self.symbol:
            address = result.library.get_pointer_to_function(result.fndesc.mangled_name)
            if not address:
                raise RuntimeError(f"{self.module}.{self.name}{self.argtypes}: no machine code to call")
            llvm.add_symbol(self.symbol, address)


@intrinsic
def _unlinked(typingctx: Any, callee: Any, args: Any) -> Any:
    """``unlinked(kernel, (a, b, ...))`` in a kernel: ``kernel(a, b, ...)``, called by its symbol
    instead of linked in. numba links a callee's LLVM module into its caller's and optimises and
    generates code for the whole again, so a large callee costs every caller its compilation once
    more: the step loop's final module was 67,000 instructions after optimisation, 10,000 of them
    its own, and took 6.9 s of LLVM (the SVD, the QP, the dynamics and the distance again). Called
    by symbol, the callee's code is the one its own compilation made; a kernel loaded from the
    cache first loads the callee (:class:`_LoadCallee`)."""
    sig = typingctx.resolve_function_type(callee, tuple(args.types), {})
    if sig is None or tuple(sig.args) != tuple(args.types):  # the call passes the values as they are
        return None
    dispatcher = callee.dispatcher

    def codegen(context: Any, builder: Any, signature: Any, llargs: Any) -> Any:
        result = dispatcher.get_compile_result(sig)
        fn = dispatcher.py_func
        signature = result.signature
        symbol = result.fndesc.mangled_name
        loader = _LoadCallee(fn.__module__, fn.__qualname__, tuple(signature.args), signature.return_type, symbol)
        context.active_code_library._reload_init.add(loader)
        items = [builder.extract_value(llargs[1], i) for i in range(len(args.types))]
        return context.call_internal(builder, result.fndesc, signature, items)

    return sig.return_type(callee, args), codegen


#: :func:`_unlinked` as kernels call it, ``unlinked(kernel, (a, b, ...))`` (numba supplies the
#: typing context).
unlinked: Any = _unlinked


def park_linking_modules() -> int:
    """Keep as bitcode, instead of parsed, the LLVM module numba holds for every loaded kernel in
    case a later compilation links it in (it parses it when it loads a kernel from the cache):
    about 40 MiB of a process that has loaded every kernel and compiles nothing more. Then give
    the heap's free pages back to the system (:func:`_trim_heap`): the parked modules', and
    whatever else the process freed since (the API calls this again after rehearsing a request).
    A compilation that does link one parses it again then. Last, drop this process's mappings of
    LLVM's library pages (:func:`release_library_pages`), which only a compilation uses. Returns
    how many modules were parked (none if numba's code library no longer looks as expected: then
    no module is changed)."""
    parked = _park()  # in a function of its own: its last module is disposed of when it returns
    _trim_heap()
    release_library_pages("libllvmlite")  # last: LLVM's code runs as it disposes of modules
    return parked


def _park() -> int:
    parked = 0
    for dispatcher in KERNELS:
        for result in list(dispatcher.overloads.values()):
            library = result.library
            module = getattr(library, "_shared_module", None)
            if module is None or not hasattr(library, "_get_module_for_linking"):
                continue
            library._get_module_for_linking = _relinker(library, module.as_bitcode())
            library._shared_module = None
            parked += 1
    return parked


def _trim_heap() -> None:
    """Give the heap's free pages back to the system (glibc's ``malloc_trim``; elsewhere nothing):
    LLVM frees the parked modules into the heap, which would otherwise keep them in the RSS."""
    with contextlib.suppress(AttributeError, OSError):
        ctypes.CDLL(None).malloc_trim(0)


#: A mapping's line in ``/proc/self/smaps``: start, end, permissions and the file, if any.
_MAPPING = re.compile(r"^([0-9a-f]+)-([0-9a-f]+) (\S{4}) \S+ \S+ \S+ *(.*)$")
#: A mapping's copied-on-write pages: resident (``Anonymous``, ``Private_Dirty``) or swapped out
#: (``Swap``, which ``Anonymous`` does not count).
_COPIED = ("Anonymous", "Swap", "Private_Dirty")


def release_library_pages(name: str, smaps: str = "/proc/self/smaps") -> int:
    """Unmap from this process the resident pages of the shared library whose file name starts
    with ``name`` wherever they are the file's own, unmodified: read-only private mappings with
    no copied-on-write page, resident or swapped out. They stay in the page cache, and whatever
    runs their code later faults them back in from there; the library's data, and the parts the
    loader relocated, are not touched. Returns the KiB released (0 where ``/proc`` or ``madvise``
    is missing).

    For LLVM's library (``libllvmlite.so``, 178 MB): Linux 6.x maps it in large folios, so each
    process that loads it counts 60-100 MiB of it in its RSS although only a compilation, or the
    loading of a cached kernel, runs its code."""
    advise = getattr(mmap, "MADV_DONTNEED", None)
    if advise is None:
        return 0
    try:
        with open(smaps) as file:
            text = file.read()  # at once: the file changes as the process does
        madvise = ctypes.CDLL(None, use_errno=True).madvise
    except (OSError, AttributeError):
        return 0
    madvise.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int]
    found: list[tuple[int, int, dict[str, int]]] = []  # (start, end, {field: KiB}) of each candidate
    fields: dict[str, int] | None = None  # the current mapping's, if it is a candidate
    for line in text.splitlines():
        head = _MAPPING.match(line)
        if head:
            start, end, perms, path = head.groups()
            fields = None
            if os.path.basename(path).startswith(name) and "w" not in perms and perms.endswith("p"):
                fields = {}
                found.append((int(start, 16), int(end, 16), fields))
        elif fields is not None:
            key, _, value = line.partition(":")
            if value.strip().endswith("kB"):
                fields[key] = int(value.split()[0])
    released = 0
    for start, end, kib in found:
        # a copied page means the loader relocated the mapping (RELRO): the process's own data,
        # which MADV_DONTNEED would throw away (a field not read counts as a copied page)
        clean = all(kib.get(key, -1) == 0 for key in _COPIED)
        if clean and kib.get("Rss", 0) > 0 and madvise(start, end - start, advise) == 0:
            released += kib["Rss"]
    return released


def _relinker(library: Any, bitcode: bytes) -> Callable[[], Any]:
    def module_for_linking() -> Any:
        library._shared_module = llvm.parse_bitcode(bitcode)
        del library._get_module_for_linking  # numba's own method again, which returns it
        return library._shared_module

    return module_for_linking
