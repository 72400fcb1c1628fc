"""``@native``: marks a hot per-star loop that the flight image compiles to machine code.

MicroPython compiles a function decorated ``@micropython.native`` to Thumb-2 instead of
bytecode (17-32 % fewer instructions for the firmware's per-star loops on the Cortex-M4F
build, ``docs/mcu_board.md``), but only a port with a native emitter accepts the decorator:
the WebAssembly port and the unix port frozen without ``-march`` refuse it at compile time,
and CPython has no ``micropython`` module.  So the source says ``@native``, which is this
identity everywhere, and the staging of an image for a native-capable build
(``lodestar.regress.unixport.stage_mcu_image(native=True)``: the Cortex-M4F build) rewrites
each ``@native`` line to ``@micropython.native`` and the import of this module to ``import
micropython``, line for line.  The same source computes the same values either way: the
native emitter runs the same operations on the same objects.

It also marks the functions with many locals that every tracking frame calls: a bytecode
function whose frame (locals, value stack) exceeds 11 words takes it from the GC heap for
each call and frees it on return (MicroPython's ``py/objfun.c``, ``VM_MAX_STATE_ON_STACK``),
which costs the allocator's search and blocks that the collection threshold counts; native
code keeps its locals on the C stack.  Not for a function that re-raises (a bare ``raise``)
or raises ``from``: the native emitter refuses both.  Nor where the lost-in-space frame's
peak is made: the collector scans the C stack, and a native frame can keep a reference its
source dropped (``stars = None``) in a slot, so ``process``, ``_solve_vectors``,
``identify`` and the search's helpers (``verify``, ``quaternion``, the solution) native
raised that frame's live peak by 0.8-2.7 KB and the executive loop ran out of its heap."""


def native(function):
    """``function`` itself (see the module docstring)."""
    return function
