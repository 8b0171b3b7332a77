"""The hop-count gradient from one source robot (Rubenstein et al., Science 2014).

The building block of Kilobot self-assembly: the source holds gradient 0; every other robot
holds one more than the smallest gradient it hears, so its value converges to its hop distance
from the source in the communication graph.

Message (kilolib v2, type 1)::

    data[0..1]  gradient  uint16, hops from the source (0xFFFF: not yet known)

Two update rules:

* **monotone** (``refresh_s = 0``, the classic kilobotics example): a robot lowers its value
  whenever it hears ``g + 1 < own``; values only fall, so with loss it still converges.
* **self-healing** (``refresh_s > 0``): a robot keeps the smallest gradient heard in the current
  window of ``refresh_s`` seconds and, at the end of each window, adopts ``min + 1`` (or
  "unknown" if it heard nothing), so the gradient re-forms when robots crash or are removed.

LED: the source is white; others cycle red, green, blue, yellow, magenta, cyan by gradient.
"""

from __future__ import annotations

from kilonet.message import Layout, Message
from kilonet.robot import Kilobot

__all__ = ["GRADIENT", "UNKNOWN", "Gradient"]

GRADIENT = Layout("gradient", type=1, fields=[("gradient", "H")])
UNKNOWN = 0xFFFF

_PALETTE = [(3, 0, 0), (0, 3, 0), (0, 0, 3), (3, 3, 0), (3, 0, 3), (0, 3, 3)]


def _palette_key() -> list[tuple[tuple[int, int, int], str]]:
    """What each palette colour shows: the gradients that are equal modulo its length (0 is
    the source, shown white).

    >>> _palette_key()[:2]
    [((3, 0, 0), 'gradient 6, 12, …'), ((0, 3, 0), 'gradient 1, 7, …')]
    """
    n = len(_PALETTE)
    return [(c, f"gradient {k or n}, {(k or n) + n}, …") for k, c in enumerate(_PALETTE)]


class Gradient(Kilobot):
    """One robot of the gradient; ``is_source`` marks the robot flashed as the source.

    Parameters
    ----------
    is_source : bool
        Whether this robot is the gradient's source (value 0).
    refresh_s : float
        0 for the monotone rule, else the self-healing window length in seconds.
    """

    LED_KEY = (
        ((3, 3, 3), "source"),
        ((0, 0, 0), "no gradient yet"),
        *_palette_key(),
    )

    def __init__(self, *, is_source: bool = False, refresh_s: float = 0.0) -> None:
        self.is_source = is_source
        self.refresh_s = refresh_s

    def setup(self) -> None:
        self.gradient = 0 if self.is_source else UNKNOWN
        self._window_min = UNKNOWN
        self._window_end = self.refresh_s
        self._message: Message | None = None
        self._show()

    def _set(self, value: int) -> None:
        if value != self.gradient:
            self.gradient = value
            self._message = None
            self.log("gradient", value=value)
            self._show()

    def _show(self) -> None:
        if self.is_source:
            self.set_color(3, 3, 3)
        elif self.gradient == UNKNOWN:
            self.set_color(0, 0, 0)
        else:
            self.set_color(*_PALETTE[self.gradient % len(_PALETTE)])

    def message_tx(self) -> Message | None:
        if self.gradient == UNKNOWN:
            return None
        if self._message is None:
            self._message = GRADIENT.pack(gradient=self.gradient)
        return self._message

    def message_rx(self, message: Message, distance_mm: int) -> None:
        if self.is_source or not GRADIENT.matches(message):
            return
        heard = GRADIENT.unpack(message).gradient
        if heard == UNKNOWN:
            return
        if self.refresh_s > 0:
            self._window_min = min(self._window_min, heard)
            # Within the first window, adopt improvements at once so the gradient forms fast.
            if self.gradient == UNKNOWN or heard + 1 < self.gradient:
                self._set(heard + 1)
        elif heard + 1 < self.gradient:
            self._set(heard + 1)

    def loop(self) -> None:
        if self.refresh_s <= 0 or self.is_source:
            return
        now_s = self.kilo_ticks / self.ticks_per_s
        if now_s >= self._window_end:
            self._window_end = now_s + self.refresh_s
            heard = self._window_min
            self._window_min = UNKNOWN
            self._set(UNKNOWN if heard == UNKNOWN else heard + 1)
