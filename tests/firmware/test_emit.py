"""The ``@native`` marker (:mod:`lodestar.firmware.emit`): the identity wherever the source
runs as it is (CPython, the WebAssembly and unix MicroPython ports)."""

from lodestar.firmware import emit


def test_native_returns_the_function_itself():
    def f(x):
        return 2 * x

    assert emit.native(f) is f
    assert emit.native(f)(3) == 6
