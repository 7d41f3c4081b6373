"""Arrays without reference counting for the closed loop's hot path (issue 34).

numba counts the references of every array it hands around (an atomic increment and decrement of
the array's owner): each named tuple of arrays a helper takes, each row view and each slice inside
the 1 kHz loop costs a pair of them, and they were most of the loop's time. :func:`borrowed`
returns its argument (an array, or a tuple / named tuple of them, nested; other members as they
are) with the arrays' owner cleared: the same data, shape and strides, so the same arithmetic and
the same results, but numba's increments and decrements of them return at once (a null owner).

The caller keeps the owners alive for as long as the borrowed arrays are used: arguments of the
compiled function are (the Python caller holds them); an array the function allocates must stay
in a variable that is used after the last use of its borrowed copy (numba frees a variable after
its last use), e.g. by :func:`keep_alive` at the end. A borrowed array must never be returned to
Python or stored where it outlives its owner.
"""

from __future__ import annotations

from numba import types
from numba.core import cgutils
from numba.extending import intrinsic


def _borrow(context, builder, ty, val):
    """``val`` of numba type ``ty`` with the owner (meminfo) and parent of every array cleared."""
    if isinstance(ty, types.Array):
        ary = context.make_array(ty)(context, builder, value=val)
        ary.meminfo = cgutils.get_null_value(ary.meminfo.type)
        ary.parent = cgutils.get_null_value(ary.parent.type)
        return ary._getvalue()
    if isinstance(ty, types.BaseTuple):
        out = val
        for k, item_ty in enumerate(ty.types):
            item = _borrow(context, builder, item_ty, builder.extract_value(val, k))
            out = builder.insert_value(out, item, k)
        return out
    return val


@intrinsic
def borrowed(typingctx, value):
    """``value`` (an array or a tuple of them, nested) without reference counting (module
    docstring): the same type, the same data.
    """

    def codegen(context, builder, signature, args):
        return _borrow(context, builder, signature.args[0], args[0])

    return value(value), codegen


@intrinsic
def keep_alive(typingctx, values):
    """Does nothing: a use of ``values`` (any value, a tuple for several) that keeps them, the
    owners of borrowed arrays, alive up to this point.
    """

    def codegen(context, builder, signature, args):
        return context.get_dummy_value()

    return types.none(values), codegen
