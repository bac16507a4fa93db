"""``python -m hexapod_driver.emulator``: the same as the ``bus_emulator`` executable."""
import sys

from hexapod_driver.emulator.cli import main

sys.exit(main())
