# MicroPython freeze manifest of the MCU image: the lodestar root, the contract, the firmware
# and the MCU side of the regression (lodestar.regress.micropython.mcu_image), as bytecode in
# flash (upstream mpy-tool).  Freeze it with
# FROZEN_MANIFEST=<this file> and LODESTAR_MCU_IMAGE=<a folder staged by
# lodestar.regress.unixport.stage_mcu_image> (the firmware lives in firmware/ of the
# checkout but is lodestar.firmware on the MCU, so the image is staged first).
import os

package("lodestar", base_path=os.environ["LODESTAR_MCU_IMAGE"])
