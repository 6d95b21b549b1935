"""The example script registers the demo case, plans it and writes its figure."""

import subprocess
import sys

from conftest import ROOT


def test_plan_and_plot_writes_its_figure(tmp_path):
    out = tmp_path / "zones.png"
    result = subprocess.run(
        [sys.executable, str(ROOT / "examples" / "python" / "plan_and_plot.py"),
         "--out", str(out), "--scan-points", "60000", "--seed", "2"],
        capture_output=True, text=True, timeout=600,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    assert "validation passed" in result.stdout, result.stdout
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert out.stat().st_size > 20_000
