"""Tests for kilonet.experiments.studies.gcs_measured: what docs/results/gcs.md's blocks read
from a run."""

from __future__ import annotations

import pytest

from kilonet.experiments.studies.gcs_measured import THIN_DEG, gcs_run


@pytest.mark.xfail(
    strict=True,
    reason="issue-29 medium: 6 of the 7 isolated seeds (seed 1) have references >= THIN_DEG; "
    "robot 16's read 169.0 deg from its estimates, a lattice triple bent by per-link "
    "systematic error (the idealised medium gives 7 of 11): THIN_DEG on estimated angles "
    "needs the model's error",
)
def test_isolated_seeds_on_a_40_robot_lattice_are_thin_frames_of_seed_and_references():
    """docs/gcs.md, "On the robot model": without occlusion the thesis's rule leaves seeds whose
    references are nearly collinear with them and whose frames hold nobody else, and those are
    the isolated ones after phase 5; the widest-triangle rule leaves none."""
    run = gcs_run(40, 1, (("gcs.until", "groups"),))
    assert run.isolated >= 3
    assert run.isolated_alone_thin == run.isolated_alone == run.isolated
    assert run.thin_frames >= run.isolated
    assert max(run.reference_angles_deg) >= THIN_DEG
    widest = gcs_run(40, 1, (("gcs.reference_rule", "best_conditioned"), ("gcs.until", "groups")))
    assert widest.isolated == 0
