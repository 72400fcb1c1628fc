"""Co-simulation of the gateware: the SystemVerilog harness (``harness.sv``), the cocotb
player that clocks it (:mod:`.player`) and the runner that builds it with Verilator, plays
frames through it and reads the records back (:mod:`.runner`)."""
