"""Trilateration with Kilobots: three robots build a frame, a fourth walks to its centroid.

* :mod:`~kilonet.protocols.follower.follower` — the frame robots and the :class:`Follower`.
* :mod:`~kilonet.protocols.follower.pivot_turns` — where a one-motor pivot turn leaves the robot.
* :mod:`~kilonet.protocols.follower.turn_calibration` — turning by timed motor pulses.
"""
