"""Loaded by every test run here: the Ctrl-C that tests send to the tools they start must reach them."""
import signal

# A run started in the background by a non-interactive shell (`cmd &`, as CI runners and scripts do)
# inherits SIGINT ignored, and an ignored signal stays ignored across exec: the tools the tests interrupt
# would never see their Ctrl-C, and Python does not install its handler over an ignored SIGINT. A
# handler of ours is reset to the default at exec, so the children start as from a terminal.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)
