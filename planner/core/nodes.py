"""Node ids: one impacter of one device, ``Node("A1", "forward")``, text ``"A1.forward"``.

Devices are named like a well plate (row letter, column number); :func:`device_key`
is the one sort key of device ids (``A2`` before ``A10``).  In files (plan.json,
CSVs) a node is always its text form.
"""

from __future__ import annotations

from typing import NamedTuple

DIRECTIONS = ("forward", "backward")


class Node(NamedTuple):
    """One impacter: its device id and its direction (``"forward"``/``"backward"``)."""

    device: str
    direction: str

    @property
    def text(self) -> str:
        """The form in files: ``"A1.forward"``."""
        return f"{self.device}.{self.direction}"

    @property
    def sign(self) -> float:
        """+1 for forward, -1 for backward: the direction the impacter pushes its slider."""
        return 1.0 if self.direction == "forward" else -1.0

    @classmethod
    def parse(cls, text: str) -> "Node":
        """``"A1.forward"`` -> ``Node("A1", "forward")``."""
        device, direction = str(text).rsplit(".", 1)
        return cls(device, direction)

    def __str__(self) -> str:
        return self.text


def device_key(device: str) -> tuple[str, int]:
    """Sort key of a device id: row letter, then column as a number."""
    return device[0], int(device[1:])


def node_key(text: str) -> tuple[str, int, str]:
    """Sort key of a node's text: its device's key, then the text."""
    return (*device_key(Node.parse(text).device), text)
