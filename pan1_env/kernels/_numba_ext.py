"""Numba plumbing shared by the kernels: compile options, stack arrays, the SLP switch, the lane count,
and a cache stamp that covers the whole kernels package.

Numba's disk cache checks only the source file of the function it loads; a kernel here inlines
helpers from the package's other modules, so a change to one of them must invalidate every kernel.
:func:`_install_package_stamp` makes the cache stamp of every kernels module depend on all of them.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic
from numba.np.arrayobj import make_array, populate_array

# numpy error model: no zero-division checks in the hot loops (a zero pivot gives inf/NaN, caught by the
# finiteness checks); fast-math without nnan/ninf, so NaN and inf tests keep working, and without reassoc
# (with it LLVM let a NaN state through the RK4 step's finiteness check: tests/test_robustness.py).
# No value-changing flag that LLVM may apply differently to two copies of the same code: numba links a
# called kernel (``_advance_arms``) into its caller's module as a weak copy, compiled again there; in the
# process that compiles them the call goes to the callee's own copy, in a process that loads the caller
# from the disk cache to the caller's copy. With contract (fused multiply-adds) or arcp (x / y as
# x · (1 / y)) the two copies rounded differently, so the first run after a change did not reproduce
# later runs bit for bit (tests/test_determinism.py; arcp's case showed on a 5-link PA arm, which the
# test covers). With afn kept, fresh and cached kernels agree there.
_JIT = {"cache": True, "error_model": "numpy", "fastmath": {"nsz", "afn"}}
# For the small passes that copy or reduce numbers and promise numpy's bytes (the critics' state, the team infos'
# reductions): no fast-math flag at all, since nsz would let LLVM drop a zero's sign (0.0 + x -> x, a select of ±0).
_EXACT = {**_JIT, "fastmath": False}

# The sub-step kernel's lane count: 4 arms at once (one AVX register of doubles), in the serial and
# the multi-threaded kernel alike (measured on this project's machine: 8 or 16 lanes were no faster
# on RK4 and about a fifth slower with the filter, whose per-lane search and larger code weigh more;
# a padded lane also costs as much as a real one).
_LANES = (0,) * 4


@intrinsic
def _local(typingctx, shape, dtype):
    """``_local((t_1, …, t_d), dtype)``: an uninitialised C-contiguous array of shape
    (len(t_1), …, len(t_d)) in the calling function's stack frame (one ``alloca`` in its entry block).

    The t_i are tuples (such as the ``kernel_sizes`` tuples), so the shape is part of their type and
    fixed at compile time; with the loops over it unrolled, LLVM promotes the array's entries to
    registers, which heap scratch arrays (that may alias any other array) do not allow. The array is
    valid until the calling function returns and must not be returned or stored: use it only for
    scratch space inside one kernel. The one exception is a function numba inlines into the kernel
    (``inline="always"``, an inlining of numba's own IR before typing: :mod:`.scratch`), whose
    ``alloca`` is then the kernel's and whose arrays it may return to the kernel. (Numba has no
    public stack array: numba issues #2108, #5084.)"""
    if not (isinstance(shape, types.BaseTuple) and all(isinstance(t, types.BaseTuple) for t in shape.types)
            and isinstance(dtype, (types.NumberClass, types.DType))):
        return None
    dims = tuple(len(t) for t in shape.types)
    item = dtype.dtype
    array_type = types.Array(item, len(dims), "C")

    def codegen(context, builder, signature, args):
        data_type = context.get_data_type(item)
        count = int(np.prod(dims))
        data = cgutils.alloca_once(builder, data_type, size=context.get_constant(types.intp, max(count, 1)))
        itemsize = context.get_abi_sizeof(data_type)
        strides = [itemsize * int(np.prod(dims[a + 1:])) for a in range(len(dims))]
        array = make_array(array_type)(context, builder)
        intp = lambda value: context.get_constant(types.intp, value)  # noqa: E731
        populate_array(array, data=data, shape=[intp(d) for d in dims], strides=[intp(x) for x in strides],
                       itemsize=intp(itemsize), meminfo=None)
        return array._getvalue()

    return array_type(shape, dtype), codegen


@intrinsic
def _borrowed(typingctx, group):
    """``group`` (a tuple) with every array in it unreferenced: the same data, shape and strides without
    the reference count (meminfo) and Python parent. Numba takes a reference (an atomic count on a heap
    array) each time code reads an array out of a tuple and drops it later, and inside the sub-step
    kernel's loops its pruning does not remove every pair: measured, the filtered kernel ran 7-10 %
    slower with its scratch in plain tuples. An unreferenced array's count is a no-op. Only for arrays
    that outlive every use of the copy: the kernel's arguments (its caller holds them), or its own
    scratch kept to the end with :func:`_keep_alive`."""
    if not isinstance(group, types.BaseTuple):
        return None

    def codegen(context, builder, signature, args):
        value = args[0]
        for index, member in enumerate(group.types):
            if isinstance(member, types.Array):
                array = make_array(member)(context, builder, value=builder.extract_value(value, index))
                array.meminfo = context.get_constant_null(types.MemInfoPointer(types.voidptr))
                array.parent = context.get_constant_null(types.pyobject)
                value = builder.insert_value(value, array._getvalue(), index)
        return value

    return group(group), codegen


@intrinsic
def _keep_alive(typingctx, owner):
    """Nothing, but a use of ``owner``: numba frees a variable's arrays after its last use, so scratch
    used through a :func:`_borrowed` copy is kept to this point."""
    def codegen(context, builder, signature, args):
        return context.get_dummy_value()

    return types.none(owner), codegen


@njit(**_JIT)
def _check_chunks(n_chunks):
    if n_chunks < 1:
        raise ValueError("n_chunks must be at least 1 (the multi-threaded kernels split their work into n_chunks)")


def _slp_vectorised(dispatcher):
    """Compile ``dispatcher``'s signatures with LLVM's SLP vectoriser on (numba leaves it off by
    default, ``NUMBA_SLP_VECTORIZE``, after miscompilations in older LLVMs: numba PR #8852). It is
    what packs the sub-step kernel's lanes into vector registers; the flag is set only while this
    dispatcher compiles (holding numba's compiler lock, so no other thread's compilation sees it; the
    small helpers it calls are compiled with it too) and restored after, so the user's numba code is
    compiled as the user configured it. The disk cache does not record the flag: code loaded from it
    was compiled through these dispatchers too. The flag is read when numba builds a pass manager,
    which numba on LLVM's new pass manager does per compilation (``CPUCodegen._pass_builder``,
    numba 0.68 here); with a numba without it the kernels are left as they are (the same results,
    slower).
    ``tests/test_kernels.py`` checks the vectorised kernel against the same kernel compiled without
    SLP, bit for bit."""
    from numba.core import codegen, config
    from numba.core.compiler_lock import global_compiler_lock

    if not hasattr(codegen.CPUCodegen, "_pass_builder"):
        # numba builds its pass managers once, from the first compilation: a flag set around one
        # dispatcher would not take effect (or would for all code). Leave it: same results, slower.
        return dispatcher
    compile_plain = dispatcher.compile
    dispatcher._compile_without_slp = compile_plain  # for _quick_when

    def compile_slp(sig):
        with global_compiler_lock:  # re-entrant; held by numba around every compilation
            config.reload_config()  # a changed NUMBA_* variable would otherwise reset the flag mid-way
            saved = config.SLP_VECTORIZE
            config.SLP_VECTORIZE = 1
            try:
                return compile_plain(sig)
            finally:
                config.SLP_VECTORIZE = saved

    dispatcher.compile = compile_slp
    return dispatcher


def _quick_when(dispatcher, argument: int, level: int = 1):
    """Compile ``dispatcher``'s signatures whose argument ``argument`` is not None quickly: LLVM's
    module passes at optimisation level ``level`` instead of numba's 3 (``config.OPT``, read per
    compilation in numba 0.68), without its loop and SLP vectorisers (``config.LOOP_VECTORIZE``, and
    bypassing :func:`_slp_vectorised`); the settings are restored after, under numba's compiler lock
    as there. For the generic sub-step kernel, a stand-in for a few seconds whose compilation is on a
    new kind's first step: it saves about 1 s of its 8 and the kernel steps no slower (one lane:
    nothing to vectorise). No result changes (no fast-math flag lets LLVM change a value: ``_JIT``;
    tests/test_kernels.py compares the generic kernel with the per-kind ones bit for bit)."""
    from numba.core import config, types
    from numba.core.compiler_lock import global_compiler_lock

    compile_before = dispatcher.compile
    compile_quick_path = getattr(dispatcher, "_compile_without_slp", compile_before)

    def compile_quick(sig):
        args = getattr(sig, "args", sig)
        if len(args) <= argument or isinstance(args[argument], (types.NoneType, types.Omitted)):
            return compile_before(sig)
        with global_compiler_lock:
            config.reload_config()  # as _slp_vectorised: a changed NUMBA_* variable would reset these mid-way
            saved = config.OPT, config.LOOP_VECTORIZE, config.SLP_VECTORIZE
            config.OPT, config.LOOP_VECTORIZE, config.SLP_VECTORIZE = type(saved[0])(level), 0, 0
            try:
                return compile_quick_path(sig)
            finally:
                config.OPT, config.LOOP_VECTORIZE, config.SLP_VECTORIZE = saved

    dispatcher.compile = compile_quick
    return dispatcher


_PACKAGE = Path(__file__).resolve().parent


def _install_package_stamp() -> None:
    """Give every module of this package one cache stamp: a hash of all its source files. Numba
    compares a cached kernel's stamp with its own file's only, which would keep a kernel whose inlined
    helper (in another module here) changed. Done through numba's cache locators
    (``numba.core.caching``; ``CacheImpl`` lost its underscore in numba 0.68); with a numba without
    it the package keeps numba's per-file stamps (a developer then clears the cache after an edit)."""
    try:
        from numba.core import caching
    except ImportError:  # pragma: no cover
        return
    impl = getattr(caching, "CacheImpl", None) or getattr(caching, "_CacheImpl", None)
    if impl is None or not hasattr(impl, "_locator_classes"):
        return

    def package_stamp() -> bytes:
        digest = hashlib.sha256()
        for path in sorted(_PACKAGE.glob("*.py")):
            digest.update(path.read_bytes())
        return digest.digest()

    class _PackageLocator:
        """Numba's own choice of cache place (NUMBA_CACHE_DIR, in-tree, user-wide, …), with the
        package's stamp for the kernels' files."""

        @classmethod
        def from_function(cls, py_func, py_file):
            if Path(py_file).resolve().parent != _PACKAGE:
                return None
            for other in impl._locator_classes:
                locator = None if other is cls else other.from_function(py_func, py_file)
                if locator is not None:
                    locator.get_source_stamp = package_stamp
                    return locator
            return None

    if not any(c.__name__ == "_PackageLocator" for c in impl._locator_classes):
        impl._locator_classes.insert(0, _PackageLocator)


_install_package_stamp()
