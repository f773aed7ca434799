"""The examples of examples/python run as the README shows them (small sizes, so they are quick)."""
import os
import pathlib
import subprocess
import sys

import evkit

EXAMPLES = pathlib.Path(__file__).resolve().parents[2] / "examples" / "python"
PACKAGE_ROOT = str(pathlib.Path(evkit.__file__).resolve().parents[1])  # the evkit under test


def run(script, *args, cwd):
    out = subprocess.run([sys.executable, str(EXAMPLES / script), *map(str, args)], cwd=cwd,
                         capture_output=True, text=True, env=dict(os.environ, MPLBACKEND="Agg", PYTHONPATH=PACKAGE_ROOT),
                         timeout=300)
    assert out.returncode == 0, out.stderr
    return out.stdout


def test_plot_recording(real, tmp_path):
    out = run("plot_recording.py", real("davis240c_translboxes.aedat"), "--out", "f.png", cwd=tmp_path)
    assert "162,771 events, 240x180, 82,944 ON" in out
    assert (tmp_path / "f.png").stat().st_size > 10_000


def test_convert_to_hdf5(real, tmp_path):
    out = run("convert_to_hdf5.py", real("dvxplorer_sample.aedat4"), tmp_path / "c.h5", cwd=tmp_path)
    assert "h5py reads back the same 111,954 events (t 1605537493718345 .. 1605537494308262 us)" in out


def test_deblur_side_by_side(tmp_path):
    out = run("deblur_side_by_side.py", "--size", 64, 48, "--budget", 50, "--out", "s.png", cwd=tmp_path)
    assert "EDI     PSNR" in out and "BeNeRF  PSNR" in out
    assert (tmp_path / "s.png").stat().st_size > 10_000
