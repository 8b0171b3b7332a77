"""gcs merging's fast paths against the careful ones (issue 44).

A seed sends the last TF_ROT or TF_SHIFT message again while its transform has not changed,
instead of packing it anew: every message it sends must be the one a fresh pack would give.
"""

from __future__ import annotations

import pytest

from kilonet import scenarios
from kilonet.protocols.gcs import phase6_merging
from kilonet.protocols.gcs.phase6_merging import TF_ROT, TF_SHIFT, SeedRounds, quaternion_fields


def test_a_seed_repeats_its_transform_halves_exactly_as_packed(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    reused = checked = 0
    given = SeedRounds._transform_message

    def careful(self: SeedRounds, *, rotation: bool) -> phase6_merging.Message:
        nonlocal reused, checked
        before = self._halves.get(rotation)
        message = given(self, rotation=rotation)
        sender, version = self.robot.uid, self._version_byte()
        if rotation:
            fresh = TF_ROT.pack(sender=sender, version=version, **quaternion_fields(self.rotation))
        else:
            vx, vy, vz = self.shift
            fresh = TF_SHIFT.pack(sender=sender, version=version, vx_mm=vx, vy_mm=vy, vz_mm=vz)
        assert (message.data, message.type, message.crc) == (fresh.data, fresh.type, fresh.crc)
        reused += before is not None and message is before[3]
        checked += 1
        return message

    monkeypatch.setattr(SeedRounds, "_transform_message", careful)
    result = scenarios.run(scenarios.get("gcs"), {"placement.robots": 40}, seed=2)
    assert result.summary["seeds_done"] > 0
    assert checked > 100
    assert 0 < reused < checked  # both the repeat and a new pack after a step happened
