"""A messy file from the shell: a least squares that cannot be trusted ends the posterior
run with exit 1 naming the file's lines, never a Python traceback (docs/robustness.md)."""

import numpy as np

import bayescal as bc
import bayescal.fit.simultaneous as simul
from bayescal.results.calibration import ConvergenceError


def _csv(path):
    ds = bc.simulate_room(range_mm=1000.0, n_points=40, n_walls=5, sigma_px=0.3,
                          approx_error=0.02, approx_model="gaussian", rng=3)
    rows = [",".join(f"{v:.6f}" for v in (*p, *a)) for p, a in zip(ds.pixels, ds.approx_points,
                                                                   strict=True)]
    path.write_text("u,v,x,y,z\n" + "\n".join(rows) + "\n")


def test_bayes_with_an_untrusted_start_exits_1_naming_lines(tmp_path, capsys, monkeypatch):
    real = simul.calibrate_simultaneous

    def untrusted(*args, **kw):           # the least squares refuses, naming rows 3 and 7
        res = real(*args, **{**kw, "raise_on_failure": False})
        res.converged, res.message = False, "h = 1.6e-11 sits on the bound of its domain"
        res.extras["failed_rows"] = np.array([3, 7])
        raise ConvergenceError(f"simultaneous calibration did not converge: {res.message}",
                               result=res)

    monkeypatch.setattr(simul, "calibrate_simultaneous", untrusted)
    monkeypatch.chdir(tmp_path)
    _csv(tmp_path / "d.csv")
    from bayescal.cli.main import main

    rc = main(["calibrate", "d.csv", "--method", "bayes", "--sigma-px", "0.3",
               "--sigma-scene", "2%", "--out", "out", "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 1, err
    assert "least-squares start did not converge" in err and "lines 5, 9" in err, err
    assert "Traceback" not in err and "ConvergenceError" not in err
    assert not (tmp_path / "out").exists()
