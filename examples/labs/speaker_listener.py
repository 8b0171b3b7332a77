"""Communication (Kilobotics lab 2): ``test_speaker.c`` and ``test_listener.c``, ported line
by line.

The speaker sends a message at every transmit opportunity and blinks magenta for 100 ms after
each one it sent; the listener blinks yellow for 100 ms after each one it received.

On the robots the two programs are two hex files. Here they are :class:`TestSpeaker` and
:class:`TestListener`, and :class:`SpeakerListener` runs both as one program (the robot whose
``kilo_uid`` is ``SPEAKER_UID`` speaks), so ``kilonet run --program`` can run the lab:
``speaker_listener.csv`` places the speaker (uid 0) and three listeners around it.

Changes of syntax: the C globals are attributes set in ``setup``; ``message.crc =
message_crc(&message)`` builds a new :class:`~kilonet.message.Message` (messages are
immutable); ``RGB(r, g, b)`` becomes ``set_color(r, g, b)``; ``delay(100)`` is ``yield
self.delay(100)`` in a generator ``loop``. Run::

    python -m examples.labs.speaker_listener [--seed N] [--set KEY=VALUE ...]
"""

from __future__ import annotations

from dataclasses import replace

from kilonet.message import Message, message_crc
from kilonet.robot import Kilobot

try:  # part of the examples package (python -m examples.labs.speaker_listener, the tests)
    from .lab_common import NORMAL
except ImportError:  # loaded as a file of its own (kilonet run --program ...)
    from lab_common import NORMAL

__all__ = ["SPEAKER_UID", "SpeakerListener", "TestListener", "TestSpeaker"]

#: The robot that runs test_speaker when both programs run as :class:`SpeakerListener`.
SPEAKER_UID = 0


class TestSpeaker(Kilobot):
    """``test_speaker.c``: send all the time, blink magenta once per message sent."""

    def setup(self):
        # Flag to keep track of message transmission.
        self.message_sent = 0
        # Initialize message:
        # The type is always NORMAL.
        # Some dummy data as an example.
        self.message = Message(bytes([0]), NORMAL)
        # It's important that the CRC is computed after the data has been set;
        # otherwise it would be wrong and the message would be dropped by the
        # receiver.
        self.message = replace(self.message, crc=message_crc(self.message))

    def loop(self):
        # Blink the LED magenta whenever a message is sent.
        if self.message_sent == 1:
            # Reset the flag so the LED is only blinked once per message.
            self.message_sent = 0

            self.set_color(1, 0, 1)
            yield self.delay(100)
            self.set_color(0, 0, 0)

    def message_tx(self):
        return self.message

    def message_tx_success(self):
        # Set the flag on message transmission.
        self.message_sent = 1


class TestListener(Kilobot):
    """``test_listener.c``: blink yellow once per message received."""

    def setup(self):
        # Flag to keep track of new messages.
        self.new_message = 0

    def loop(self):
        # Blink the LED yellow whenever a message is received.
        if self.new_message == 1:
            # Reset the flag so the LED is only blinked once per message.
            self.new_message = 0

            self.set_color(1, 1, 0)
            yield self.delay(100)
            self.set_color(0, 0, 0)

    def message_rx(self, message, distance):
        # Set the flag on message reception.
        self.new_message = 1


class SpeakerListener(TestSpeaker, TestListener):
    """Both programs in one: the robot with ``kilo_uid == SPEAKER_UID`` runs
    :class:`TestSpeaker`, every other robot :class:`TestListener` (which sends nothing)."""

    def setup(self):
        self.speaker = self.kilo_uid == SPEAKER_UID
        (TestSpeaker if self.speaker else TestListener).setup(self)

    def loop(self):
        yield from (TestSpeaker if self.speaker else TestListener).loop(self)

    def message_tx(self):
        return TestSpeaker.message_tx(self) if self.speaker else None

    def message_rx(self, message, distance):
        if not self.speaker:
            TestListener.message_rx(self, message, distance)


if __name__ == "__main__":
    from examples.labs import measures, world

    world.main("speaker_listener", SpeakerListener, measures.speaker_listener)
