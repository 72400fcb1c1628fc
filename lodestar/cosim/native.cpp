// Native player of the co-simulation harness: lodestar/cosim/harness.sv built with
// COSIM_NATIVE (runner.Build(native=True)) and this main, without cocotb.
//
// Raises `start`, then toggles `clk` (an eval per edge) until the harness raises `done`
// after the last word of its stimulus file.  Exit 0 then; exit 1 if the simulation ends
// before (a $fatal of the harness, with its message on stderr, also exits 1).  Plusargs
// (+stim=, +out=) reach the harness through the command line.  No VPI, no timing
// coroutines, no Python: the detector's own logic is most of the run (docs/cosim.md).
#include <cstdio>

#include "Vtop.h"
#include "verilated.h"

int main(int argc, char** argv) {
    VerilatedContext context;
    context.commandArgs(argc, argv);
    Vtop top{&context};
    top.start = 1;
    top.clk = 0;
    top.eval();
    while (!top.done && !context.gotFinish()) {
        top.clk = 1;
        top.eval();
        top.clk = 0;
        top.eval();
    }
    top.final();
    if (!top.done) {
        std::fprintf(stderr, "cosim: the harness stopped before the end of its stimulus\n");
        return 1;
    }
    return 0;
}
