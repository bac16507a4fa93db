"""The sim node and its parts: parameters, the bus master loop, the local and live buses, the bus emulator backend, the `sim` command."""
