"""``python -m hexapod_driver.emulator``: the same as the ``bus_emulator`` executable."""
import sys

from .cli import main

sys.exit(main())
