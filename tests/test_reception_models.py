"""Reception models chosen by name from the parameters: built-in and the user's own."""

from __future__ import annotations

import json

import pytest

from kilonet import Kilobot, Params, Simulation
from kilonet.app.cli import main
from kilonet.reception import GaussianRanging, TableRanging

MODEL = '''
import numpy as np
from kilonet.reception import GaussianRanging


class HalfBeyond60(GaussianRanging):
    """Loses half the receptions of links longer than 60 mm, at random from the run's stream."""

    def loss_probability(self, shares, distance_mm):
        thresholds = super().loss_probability(shares, distance_mm)
        thresholds[0] = np.maximum(thresholds[0], np.where(distance_mm > 60, 0.5, 0.0))
        return np.maximum.accumulate(thresholds, axis=0)
'''


@pytest.fixture
def user_model(tmp_path, monkeypatch):
    (tmp_path / "my_models.py").write_text(MODEL)
    monkeypatch.syspath_prepend(str(tmp_path))
    return "my_models:HalfBeyond60"


def test_the_built_in_models_by_name():
    for name, cls in (("tables", TableRanging), ("gaussian", GaussianRanging)):
        sim = Simulation(
            [[0, 0], [50, 0]], Kilobot, Params().with_overrides({"ranging.model": name})
        )
        assert type(sim.medium.reception) is cls


def _run(argv, capsys) -> dict:
    assert main(argv) == 0
    return json.loads(capsys.readouterr().out)


def test_a_users_model_runs_from_the_command_line_seeded_like_the_rest(user_model, capsys):
    base = ["run", "gradient", "--robots", "30", "--duration", "10", "--json"]
    own = [*base, "--set", f"ranging.model={user_model}"]
    a, b = _run([*own, "--seed", "1"], capsys), _run([*own, "--seed", "1"], capsys)
    c, plain = _run([*own, "--seed", "2"], capsys), _run([*base, "--seed", "1"], capsys)
    assert a["lost_random"] == b["lost_random"] > 0  # same seed, same losses
    assert a["lost_random"] != c["lost_random"]  # another seed, other draws
    assert plain["lost_random"] == 0


def test_a_users_model_from_a_toml_run_file(user_model, tmp_path, capsys):
    run = tmp_path / "run.toml"
    run.write_text(f'scenario = "gradient"\nduration_s = 5\n[ranging]\nmodel = "{user_model}"\n')
    assert _run(["run", str(run), "--robots", "20", "--json"], capsys)["lost_random"] > 0


def test_a_factory_that_gives_no_reception_model_is_refused(tmp_path, monkeypatch):
    from kilonet.params import ParamError

    (tmp_path / "bad_models.py").write_text("def make(context):\n    return 42\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    params = Params().with_overrides({"ranging.model": "bad_models:make"})
    with pytest.raises(ParamError, match="gave int, not a ReceptionModel"):
        Simulation([[0, 0], [50, 0]], Kilobot, params)
