"""Evaluation: rows for 1 / 8 inputs with and without refinement, report files, lights."""

from __future__ import annotations

import json
import math

from estimator.evaluate import HELDOUT_LIGHTS, evaluate
from materials.dataset import EVAL_SEEDS
from materials.lights import EVAL_CAMERA, EVAL_LIGHTS


def test_heldout_lights_are_not_input_lights():
    assert len(HELDOUT_LIGHTS) == len(set(HELDOUT_LIGHTS)) == 16
    inputs = {tuple(map(float, p)) for p in (EVAL_CAMERA, *EVAL_LIGHTS)}
    for p in HELDOUT_LIGHTS:
        assert min(math.dist(p, q) for q in inputs) > 0.5
        assert p[2] > 0


def test_evaluate_rows_and_report(tiny_model, tmp_path):
    report = evaluate(tiny_model, EVAL_SEEDS[:3], 32, refine_steps=3, batch_size=2, progress=False, out_dir=tmp_path)
    rows = report["rows"]
    assert [(r["inputs"], r["refined"]) for r in rows] == [(1, False), (1, True), (8, False), (8, True)]
    for r in rows:
        assert r["count"] == 3
        for k in ("mse_diffuse", "mse_normal", "mse_roughness", "mse_specular", "psnr", "ssim"):
            assert math.isfinite(r[k]), (k, r)
        assert -1 <= r["ssim"] <= 1 and r["psnr"] > 0
    assert len(report["highlight"]) == 4 and report["highlight"][0]["count"] == 1
    assert json.loads((tmp_path / "estimator_eval.json").read_text())["rows"] == rows
    assert "| 8 | yes |" in (tmp_path / "estimator_eval.md").read_text()


def test_evaluate_is_deterministic(tiny_model):
    a = evaluate(tiny_model, EVAL_SEEDS[:2], 32, progress=False)
    b = evaluate(tiny_model, EVAL_SEEDS[:2], 32, progress=False)
    strip = lambda rows: [{k: v for k, v in r.items() if k != "seconds"} for r in rows]  # noqa: E731
    assert strip(a["rows"]) == strip(b["rows"])


def test_command_line_evaluate(tiny_model, tmp_path, capsys):
    from estimator.__main__ import main

    tiny_model.save_pretrained(tmp_path / "model")
    main(["evaluate", "--model", str(tmp_path / "model"), "--num", "2", "--size", "32", "--out", str(tmp_path / "ev")])
    assert "| 1 | no |" in capsys.readouterr().out
    assert (tmp_path / "ev" / "estimator_eval.json").is_file()
