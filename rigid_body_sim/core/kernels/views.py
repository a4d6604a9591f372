"""
Views of arrays for compiled kernels: without reference counting, and by address.

A kernel's many small calls would otherwise spend as much time counting
references to the arrays they pass on (:func:`raw`, :func:`raw_slice`,
:func:`raw_tree`) and unboxing array arguments (:class:`Pinned`, :func:`pinned`)
as on arithmetic.
Under ``NUMBA_DISABLE_JIT=1`` they are ordinary numpy views.
"""

from __future__ import annotations

import math
import weakref

import numba
from numba import carray, njit, types
from numba.core import cgutils
from numba.extending import intrinsic
import numpy as np


@intrinsic
def _address(typingctx, arr, offset):
    """Pointer to element ``offset`` of the C-contiguous array ``arr`` (compiled code only)."""
    if not isinstance(arr, types.Array) or arr.layout != 'C':
        return None
    sig = types.CPointer(arr.dtype)(arr, offset)

    def codegen(context, builder, signature, args):
        ary = context.make_array(signature.args[0])(context, builder, args[0])
        return builder.gep(ary.data, [args[1]])
    return sig, codegen


def _pointer_at(dtype):
    """Return an intrinsic: the ``dtype`` pointer at an integer address (compiled code only)."""
    @intrinsic
    def pointer_at(typingctx, address):
        if not isinstance(address, types.Integer):
            return None
        sig = types.CPointer(dtype)(address)

        def codegen(context, builder, signature, args):
            return builder.inttoptr(args[0], context.get_value_type(signature.return_type))
        return sig, codegen
    return pointer_at


_float_at, _int_at = _pointer_at(types.float64), _pointer_at(types.int64)


@intrinsic
def address(typingctx, arr):
    """Return the address of the C-contiguous ``arr``'s data (an integer: a table's slot)."""
    if not isinstance(arr, types.Array) or arr.layout != 'C':
        return None

    def codegen(context, builder, signature, args):
        ary = context.make_array(signature.args[0])(context, builder, args[0])
        return builder.ptrtoint(ary.data, context.get_value_type(types.int64))
    return types.int64(arr), codegen


@njit(cache=True)
def raw(a: np.ndarray) -> np.ndarray:
    """
    Return ``a`` (C-contiguous) as a view that carries no reference count.

    numba counts references to every array a compiled function passes on or
    slices, with an atomic increment and decrement each: in the many small
    calls of a step they cost as much as the arithmetic (measured with perf:
    20 % of a pendulum step in ``NRT_incref``/``NRT_decref``). A view made from
    the data pointer has no memory-info object, so the counting is skipped. The
    caller keeps ``a`` alive while the view is used: a kernel's arguments are
    alive for the whole call, and no view outlives it.
    """
    return carray(_address(a, 0), a.shape)


@njit(cache=True)
def raw_slice(a: np.ndarray, start: int, shape: tuple) -> np.ndarray:
    """Return ``a.ravel()[start:start + prod(shape)].reshape(shape)`` as a :func:`raw` view."""
    return carray(_address(a, start), shape)


@njit(cache=True)
def pinned(table: np.ndarray, slot: int, shape: tuple) -> np.ndarray:
    """Return the float64 array of :class:`Pinned` ``table``'s ``slot`` as a :func:`raw` view."""
    return carray(_float_at(table[slot]), shape)


@njit(cache=True)
def pinned_int(table: np.ndarray, slot: int, shape: tuple) -> np.ndarray:
    """Return the int64 array of :class:`Pinned` ``table``'s ``slot`` as a :func:`raw` view."""
    return carray(_int_at(table[slot]), shape)


def _borrowable(ty) -> bool:
    """Whether ``ty`` is arrays, numbers and booleans, in tuples nested to any depth."""
    if isinstance(ty, types.BaseTuple):
        return all(_borrowable(t) for t in ty)
    return isinstance(ty, (types.Array, types.Number, types.Boolean))


def _borrow(context, builder, ty, value):
    """Return ``value`` of type ``ty`` with its arrays' memory-info and parent pointers null."""
    if isinstance(ty, types.Array):
        ary = context.make_array(ty)(context, builder, value)
        ary.meminfo = cgutils.get_null_value(ary.meminfo.type)
        ary.parent = cgutils.get_null_value(ary.parent.type)
        return ary._getvalue()
    if isinstance(ty, types.BaseTuple):
        items = [_borrow(context, builder, t, builder.extract_value(value, k))
                 for k, t in enumerate(ty)]
        return context.make_tuple(builder, ty, items)
    return value


@intrinsic
def raw_tree(typingctx, tree):
    """
    Return ``tree`` (arrays and numbers in nested tuples) with every array a :func:`raw` view.

    The same types as ``tree``, any layout: each array's data, shape and strides are
    kept and its memory-info and parent pointers set to null, so passing the tree on
    costs no atomic counting. A tuple of 40 arrays passed to a helper costs 80 atomic
    operations without it (the helper counts every member in and out, whatever it
    reads). The caller keeps ``tree``'s arrays alive while the views are used (a
    kernel's own arguments are), and no view may be returned to Python: it would come
    back as an array owning nothing.
    """
    if not _borrowable(tree):
        return None

    def codegen(context, builder, signature, args):
        return _borrow(context, builder, signature.args[0], args[0])
    return tree(tree), codegen


if numba.config.DISABLE_JIT:
    # Plain Python (debugging): the views are ordinary numpy views, and a pinned
    # table's addresses are looked up among the arrays the tables keep (alive).
    _PINNED = weakref.WeakValueDictionary()

    def raw(a: np.ndarray) -> np.ndarray:   # noqa: F811
        return a

    def raw_slice(a: np.ndarray, start: int, shape: tuple) -> np.ndarray:   # noqa: F811
        return a.reshape(-1)[start:start + math.prod(shape)].reshape(shape)

    def pinned(table: np.ndarray, slot: int, shape: tuple) -> np.ndarray:   # noqa: F811
        return _PINNED[int(table[slot])].reshape(-1)[:math.prod(shape)].reshape(shape)

    pinned_int = pinned   # noqa: F811

    def address(a: np.ndarray) -> int:   # noqa: F811
        at = a.__array_interface__['data'][0]
        _PINNED[at] = a
        return at

    def raw_tree(tree: tuple) -> tuple:   # noqa: F811
        return tree


class Pinned:
    """
    Arrays that a kernel uses across many calls, passed as one int64 table.

    Every array argument costs a compiled call about 65 ns to unbox (measured:
    a call with 14 small arrays takes 0.95 µs, one with a table and 4 arrays
    0.5 µs), more than the arithmetic of a small step. The arrays a step reads
    or writes in place across calls (model, workspaces, work tally, outputs)
    are therefore passed as a table: slot ``k < len(arrays)`` holds the address
    of ``arrays[k]``, the slots after them the integers of ``values``. The
    kernel makes :func:`raw` views of them with :func:`pinned`. This object
    keeps the arrays alive: the table is valid while it exists, and the arrays
    must never be resized (none of them ever is: they are replaced).

    Parameters
    ----------
    arrays : sequence of ndarray
        C-contiguous float64 or int64 arrays.
    values : sequence of int
        Sizes, flags and codes the kernel reads from the slots after them.
    key : object
        What the table was built for (the caller's identity check).

    """

    __slots__ = ('arrays', 'table', 'key')

    def __init__(self, arrays, values=(), key=None) -> None:
        for k, a in enumerate(arrays):
            if a.dtype not in (np.float64, np.int64) or not a.flags.c_contiguous:
                raise ValueError(f'arrays[{k}]: expected a C-contiguous float64 or int64 '
                                 f'array, got {a.dtype} with flags {a.flags}')
        self.arrays = tuple(arrays)
        self.key = key
        addresses = [a.__array_interface__['data'][0] for a in self.arrays]
        self.table = np.array(addresses + [int(v) for v in values], dtype=np.int64)
        if numba.config.DISABLE_JIT:
            _PINNED.update(zip(addresses, self.arrays))
