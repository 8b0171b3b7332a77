"""Phase 2: seed election (thesis §4.2, §5.3.2 "Phase 2").

Rounds, each a window on the robot's clock:

* **top** (``gcs.elect_s``): every robot broadcasts its ID as a candidate; a robot that hears no
  greater ID (from this round or from its phase-1 table) becomes a seed.
* **bottom** round k (``gcs.elect_s``): the participating non-seeds (all of them in round 1;
  afterwards those asked to) broadcast their IDs as candidates; one that hears no greater
  candidate ID becomes a seed. Seeds announce themselves in every round.
* **check** after each bottom round (``gcs.check_s``): a non-seed must hear ≥ 2 seeds, a seed
  ≥ 1 other seed; a robot that does not broadcasts a re-election request, and non-seeds that
  hear one (and the asking robot itself) take part in the next bottom round.

After ``gcs.reelections`` re-elections a robot whose condition still fails logs
``seed_check_failed`` (the topology allows no better) and the phase ends anyway.

Message (type 20 ELECT, 4 bytes)::

    sender:uint16  round:uint8  status:uint8   (0 candidate, 1 seed, 2 non-seed, 3 request)
"""

from __future__ import annotations

from kilonet.message import Message
from kilonet.protocols.gcs.base import GcsParams, GcsStage, Phase, gcs_layout

__all__ = ["ELECT", "SeedElection", "seed_condition_met"]

ELECT = gcs_layout("elect", type=20, fields=[("round", "B"), ("status", "B")])
CANDIDATE, SEED, NON_SEED, REQUEST = 0, 1, 2, 3


def seed_condition_met(seeds_heard: int, *, is_seed: bool) -> bool:
    """The seed check (thesis §4.2): a non-seed must hear at least two seeds and a seed at
    least one other seed, "to ensure that enough of these local coordinate systems are
    distributed amongst the swarm" (a robot located in two frames can link them in phase 5).

    Examples
    --------
    >>> seed_condition_met(1, is_seed=True), seed_condition_met(1, is_seed=False)
    (True, False)
    """
    return seeds_heard >= (1 if is_seed else 2)


class SeedElection(Phase):
    """Phase 2 on one robot."""

    name = GcsStage.SEEDS

    def start(self) -> None:
        r = self.robot
        p = self.params
        self.start_tick = r.kilo_ticks
        self.round = 0
        self.stage = "elect"
        self.participating = True
        self.greater_heard = any(uid > r.uid for uid in r.table.ids())
        self.request_heard = False
        r.seeds = set()
        r.is_seed = False
        # Stage boundaries in ticks from the phase start: top, then (bottom, check) pairs.
        tps = r.ticks_per_s
        bounds, t = [], 0.0
        for _ in range(p.reelections + 2):
            t += p.elect_s
            bounds.append(("elect", t))
            if len(bounds) > 1:
                t += p.check_s
                bounds.append(("check", t))
        self.schedule = [(stage, round(end * tps)) for stage, end in bounds]
        self.stage_index = 0

    @staticmethod
    def window_s(p: GcsParams) -> float:
        """The phase's window, s: the top election, then ``gcs.reelections`` + 1 bottom
        elections, each followed by a check."""
        return p.elect_s * (p.reelections + 2) + p.check_s * (p.reelections + 1)

    def loop(self) -> None:
        self._close_stages(self.robot.kilo_ticks - self.start_tick)

    def _close_stages(self, elapsed: float) -> None:
        schedule = self.schedule
        while self.stage_index < len(schedule) and elapsed >= schedule[self.stage_index][1]:
            stage, _ = schedule[self.stage_index]
            self.stage_index += 1
            if stage == "elect":
                self._end_election()
            else:
                self._end_check()

    def _end_election(self) -> None:
        r = self.robot
        if self.participating and not r.is_seed and not self.greater_heard:
            r.is_seed = True
            r.log("seed", round=self.round)
        if self.round == 0:  # the top election is followed at once by the first bottom one
            self.round = 1
            self.participating = not r.is_seed
            self.greater_heard = False
        else:
            self.stage = "check"

    def _satisfied(self) -> bool:
        r = self.robot
        return seed_condition_met(len(r.seeds), is_seed=r.is_seed)

    def _end_check(self) -> None:
        r = self.robot
        self.round += 1
        self.participating = not r.is_seed and (self.request_heard or not self._satisfied())
        self.request_heard = False
        self.greater_heard = False
        self.stage = "elect"
        if self.stage_index >= len(self.schedule) and not self._satisfied():
            r.log("seed_check_failed", seeds=len(r.seeds), is_seed=r.is_seed)

    def finish(self) -> None:
        r = self.robot
        self._close_stages(float("inf"))  # the window closed: settle the last check too
        if r.is_seed:
            r.role = "seed"
        r.log("role", seed=r.is_seed, seeds_seen=len(r.seeds))

    def _status(self) -> int:
        r = self.robot
        if r.is_seed:
            return SEED
        if self.stage == "check":
            return NON_SEED if self._satisfied() else REQUEST
        return CANDIDATE if self.participating else NON_SEED

    def message_tx(self) -> Message | None:
        r = self.robot
        return ELECT.pack(sender=r.uid, round=self.round, status=self._status())

    def message_rx(self, message: Message, distance_mm: int) -> None:
        if not ELECT.matches(message):
            return
        r = self.robot
        m = ELECT.unpack(message)
        if m.status == SEED:
            r.seeds.add(m.sender)
        elif m.status == CANDIDATE and m.round == self.round and m.sender > r.uid:
            self.greater_heard = True
        elif m.status == REQUEST and m.round == self.round:
            self.request_heard = True
