"""The whole star tracker in the loop (``lodestar fly``, ``docs/fly.md``): the spacecraft on a
trajectory with a gyro (``trajectory``), the MT9P031 register model on the two-wire bus
(``mt9p031``), frames rendered at the sensor's frame period with the settings the firmware
wrote, the gateware as the Verilated board top (``verilated``, pin by pin) or its golden
model (``golden_top``), the MCU's peripherals (``bus``) under the unchanged flight executive
and link master, the MCU's time per frame (``mcu``), fault scenarios (``faults``), the loop
(``twin``) and its outputs (``report``)."""
