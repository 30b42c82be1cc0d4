"""
The e-stop latch: once tripped, the hold command at every tick until it is reset.

A ``false`` on the e-stop topic does not clear it: only an explicit reset does, so a lost or
repeated message can never release the arm.
"""


class EStop:
    """A latched emergency stop."""

    def __init__(self):
        """Start released."""
        self.latched = False

    def trip(self) -> bool:
        """Latch; return True when this latched it (it was released)."""
        was, self.latched = self.latched, True
        return not was

    def reset(self) -> bool:
        """Release; return True when it was latched."""
        was, self.latched = self.latched, False
        return was
