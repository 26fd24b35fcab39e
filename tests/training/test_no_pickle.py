"""No production module pickles: checkpoints are safetensors + JSON (training.checkpoint)
and models load through from_pretrained. A pickle executes code on load, and ties a file
to the classes that wrote it."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
#: The packages (production code); tests and scripts may do what they like.
PACKAGES = ("kernels", "materials", "relight", "estimator", "matcap", "training")
PICKLING = re.compile(
    r"\btorch\.(load|save)\s*\(|\bimport\s+(c?pickle|dill|joblib)\b|\bfrom\s+(c?pickle|dill)\s+import|weights_only\s*=\s*False"
)


def test_no_module_calls_torch_load_save_or_pickle():
    offenders = []
    for package in PACKAGES:
        files = sorted((ROOT / package).rglob("*.py"))
        assert files, f"{package}: no sources found"
        for path in files:
            for number, line in enumerate(path.read_text().splitlines(), 1):
                if PICKLING.search(line):
                    offenders.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()}")
    assert not offenders, "\n".join(offenders)
