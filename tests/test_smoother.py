"""The RTS smoother (:mod:`lde.replay.smoother`, ``lde replay --smooth``): the backward pass against
filterpy's
``rts_smoother`` and against the exact posterior of a small linear-Gaussian model (with the input
term filterpy lacks), the traced forward pass against the causal float replay, a crosswind step's
edge, and the CLI."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from lde.can.profiles import load_profile
from lde.cli import main
from lde.estimator import lateral as E
from lde.io import McapLog, read_log
from lde.params import load_vehicle
from lde.replay import smoother as S
from lde.replay.replay import CSV_COLUMNS, STATUS_COLUMNS, replay
from lde.status import VALID

DATA = Path(__file__).parent / "data"
SAMPLE = DATA / "sample_linear.log"
TRUTH = DATA / "sample_linear_truth.csv"
SAMPLE_VEHICLE = DATA / "sample_linear_vehicle.toml"
SMOOTH_NAMES = [name for name, _, _ in S.SMOOTHED]


# ----------------------------------------------------------------- a linear model with known answers


def _phi_entries(vx: float, p: np.ndarray) -> np.ndarray:
    """Phi's 7 entries (T_F order) of the lateral model at speed vx (lde.estimator.lateral's propagation)."""
    m, iz, lf, lr, dt, cf, cr = (p[i] for i in (E.P_M, E.P_IZ, E.P_LF, E.P_LR, E.P_DT, E.P_CF, E.P_CR))
    a00 = -2.0 * (cf + cr) / (m * vx)
    a01 = -1.0 - 2.0 * (lf * cf - lr * cr) / (m * vx * vx)
    a10 = -2.0 * (lf * cf - lr * cr) / iz
    a11 = -2.0 * (lf * lf * cf + lr * lr * cr) / (iz * vx)
    return np.array([1 + a00 * dt, a01 * dt, dt / (m * vx), dt / (m * vx), a10 * dt, 1 + a11 * dt, dt / iz])


def _phi(f: np.ndarray) -> np.ndarray:
    F = np.eye(5)
    F[0, 0], F[0, 1], F[0, 2], F[0, 4] = f[0], f[1], f[2], f[3]
    F[1, 0], F[1, 1], F[1, 3] = f[4], f[5], f[6]
    return F


@pytest.fixture(scope="module")
def model():
    """The lateral filter's matrices along a speed profile (time-varying Phi), its yaw-rate and
    lateral-acceleration measurement rows, and a seeded simulated truth with a steering input."""
    p = E.params_vector(load_vehicle(SAMPLE_VEHICLE))
    rng = np.random.default_rng(7)
    n = 60
    vx = 25.0 + 5.0 * np.sin(np.arange(n) / 9.0)
    F = [_phi(_phi_entries(v, p)) for v in vx]
    dt, m, cf, cr, s = p[E.P_DT], p[E.P_M], p[E.P_CF], p[E.P_CR], 1.0
    Q = np.diag([p[E.P_QB], p[E.P_QR], p[E.P_QFA], p[E.P_QMA], p[E.P_QFB]]) * dt
    H = np.array([[0, 1, 0, 0, 0], [-2 * s * (cf + cr) / m, 0, 1 / m, 0, 0]], float)
    R = np.diag([p[E.P_RR], p[E.P_RA]])
    P0 = np.diag([p[E.P_P0B], p[E.P_P0R], p[E.P_P0FA], p[E.P_P0MA], p[E.P_P0FB]]) ** 2
    delta = 0.02 * np.sin(np.arange(n) / 5.0)  # road-wheel angle [rad]
    Eu = np.array(
        [
            [2 * cf / (m * v) * dt * d, 2 * p[E.P_LF] * cf / p[E.P_IZ] * dt * d]
            for v, d in zip(vx, delta, strict=True)
        ]
    )
    x = rng.multivariate_normal(np.zeros(5), P0)
    z = []
    for k in range(n):
        z.append(H @ x + rng.multivariate_normal(np.zeros(2), R))
        x = F[k] @ x + np.r_[Eu[k], 0, 0, 0] + rng.multivariate_normal(np.zeros(5), Q)
    return {"n": n, "F": F, "Q": Q, "H": H, "R": R, "P0": P0, "Eu": Eu, "z": np.array(z), "vx": vx, "p": p}


def _forward(md, with_input: bool):
    """Kalman filter (filterpy) over the model: per step update with z_k, then predict (the order of
    lde's step); the trace rows (T_* layout) and the filtered Xs, Ps."""
    from filterpy.kalman import KalmanFilter

    kf = KalmanFilter(dim_x=5, dim_z=2)
    kf.x = np.zeros((5, 1))
    kf.P = md["P0"].copy()
    kf.H, kf.R = md["H"], md["R"]
    n = md["n"]
    rows = np.zeros((n, S.NT))
    xs, ps = np.zeros((n, 5)), np.zeros((n, 5, 5))
    for k in range(n):
        kf.update(md["z"][k].reshape(2, 1))
        xs[k], ps[k] = kf.x[:, 0], kf.P
        eu = md["Eu"][k] if with_input else np.zeros(2)
        kf.F, kf.Q = md["F"][k], md["Q"]
        kf.x = kf.F @ kf.x + np.r_[eu, 0, 0, 0].reshape(5, 1)
        kf.P = kf.F @ kf.P @ kf.F.T + kf.Q
        r = rows[k]
        r[S.T_PROP] = 1.0
        r[S.T_F : S.T_F + 7] = _phi_entries(md["vx"][k], md["p"])
        r[S.T_EU : S.T_EU + 2] = eu
        r[S.T_Q : S.T_Q + 5] = np.diag(md["Q"])
        r[S.T_X : S.T_X + 5] = kf.x[:, 0]
        r[S.T_P : S.T_P + 15] = kf.P[np.triu_indices(5)]
    return rows, xs, ps


def _backward(rows):
    n = len(rows)
    ox, op, of = np.empty((n, 5)), np.empty((n, 5)), np.empty((n, 5))
    bad = S.rts_backward(rows, np.zeros(5), np.zeros((5, 5)), np.zeros(1, np.int64), ox, op, of)
    assert bad == 0
    return ox, op, of


def _close(a, b, scale):
    """Equal to 1e-6 of each state's own scale (the states span 1e-4 rad to 1e3 N)."""
    np.testing.assert_allclose(a / scale, b / scale, rtol=0, atol=1e-6)


def test_backward_pass_is_filterpys_rts_smoother_on_the_same_matrices(model):
    """No input term (filterpy's rts_smoother has none): the same smoothed means and variances as
    filterpy, with its convention Fs[k+1] = the transition from step k to k+1."""
    from filterpy.kalman import KalmanFilter

    rows, xs, ps = _forward(model, with_input=False)
    ox, op, of = _backward(rows)
    scale = np.sqrt(np.diag(model["P0"]))
    _close(of, xs, scale)  # the filtered state recovered from the step's own propagation
    n = model["n"]
    Fs = [np.eye(5)] + model["F"][: n - 1]
    Qs = [model["Q"]] * n
    xr, pr, _, _ = KalmanFilter(dim_x=5, dim_z=2).rts_smoother(xs.reshape(n, 5, 1), ps, Fs, Qs)
    _close(ox, xr[:, :, 0], scale)
    np.testing.assert_allclose(op, np.diagonal(pr, axis1=1, axis2=2), rtol=1e-6)
    assert not np.allclose(ox, xs)  # smoothing changed something


def test_backward_pass_is_the_exact_posterior_mean_with_an_input(model):
    """With the steering input E u, the smoothed means are the posterior mean of the joint Gaussian
    of all states given all measurements (computed directly, dense)."""
    rows, _, _ = _forward(model, with_input=True)
    ox, _, _ = _backward(rows)
    n, F, Q, H, R, P0, Eu = (model[k] for k in ("n", "F", "Q", "H", "R", "P0", "Eu"))
    # x = mu + L w, w = [x0 noise, process noises]: build mean and covariance of the stacked states
    mu = np.zeros((n, 5))
    for k in range(1, n):
        mu[k] = F[k - 1] @ mu[k - 1] + np.r_[Eu[k - 1], 0, 0, 0]
    cov = np.zeros((5 * n, 5 * n))
    T = [np.eye(5)]  # cov via x_k = Phi x_{k-1} + w
    blocks = [P0]
    for k in range(1, n):
        blocks.append(F[k - 1] @ blocks[-1] @ F[k - 1].T + Q)
    for i in range(n):
        cov[5 * i : 5 * i + 5, 5 * i : 5 * i + 5] = blocks[i]
        A = np.eye(5)
        for j in range(i + 1, n):
            A = F[j - 1] @ A
            c = A @ blocks[i]
            cov[5 * j : 5 * j + 5, 5 * i : 5 * i + 5] = c
            cov[5 * i : 5 * i + 5, 5 * j : 5 * j + 5] = c.T
    del T
    Hb = np.kron(np.eye(n), H)
    Rb = np.kron(np.eye(n), R)
    z = model["z"].reshape(-1)
    gain = cov @ Hb.T @ np.linalg.inv(Hb @ cov @ Hb.T + Rb)
    post = (mu.reshape(-1) + gain @ (z - Hb @ mu.reshape(-1))).reshape(n, 5)
    _close(ox, post, np.sqrt(np.diag(P0)))


def test_a_held_step_is_not_smoothed_across():
    """A held step (no propagation) ends a run: its smoothed value is its state, and the step
    before it gets its filtered value."""
    rows = np.zeros((3, S.NT))
    rows[:, S.T_X : S.T_X + 5] = [[1, 2, 3, 4, 5], [6, 7, 8, 9, 10], [11, 12, 13, 14, 15]]
    rows[0, S.T_PROP] = 1.0
    rows[0, S.T_F : S.T_F + 7] = [1, 0, 0, 0, 0, 1, 0]
    rows[0, S.T_P : S.T_P + 15] = np.eye(5)[np.triu_indices(5)]
    ox, _, of = _backward(rows)
    np.testing.assert_array_equal(ox[1:], rows[1:, S.T_X : S.T_X + 5])
    np.testing.assert_array_equal(ox[0], of[0])


# ----------------------------------------------------------------- the data path


@pytest.fixture(scope="module")
def sample():
    frames = read_log(SAMPLE).frames
    res = replay(
        frames, load_profile("lde"), load_vehicle(SAMPLE_VEHICLE), "float", output_frames=False, smooth=True
    )
    return frames, res


def test_traced_forward_pass_is_the_causal_float_replay(sample):
    frames, res = sample
    spill = S.TraceSpill()
    try:
        eng = S.TracingEngine(load_profile("lde"), load_vehicle(SAMPLE_VEHICLE), spill)
        block = eng.feed(frames.sort(), final=True)
        spill.finish()
        np.testing.assert_array_equal(block.est, res.block.est)
        np.testing.assert_array_equal(block.status, res.status)
        ox, _, of = _backward(spill.read(0, spill.n))
    finally:
        spill.remove()
    # each row's recovered filtered state is that row's causal estimate (no shift of a step)
    est = res.block
    causal = np.c_[est.beta, est.yaw_rate, est.fw_wind, est.mw_wind, est.fw - est.fw_wind]
    _close(of, causal, np.array([1e-3, 1e-2, 1e3, 1e3, 1e3]))
    np.testing.assert_allclose(res.smooth[:, S.S_FW], ox[:, 2] + ox[:, 4], rtol=0, atol=1e-9)


def _half_time(t, y, edge):
    """First time after edge - 1 s at which y is past half of its step (levels 0.8 s before / after)."""
    before, after = np.interp(edge - 0.8, t, y), np.interp(edge + 0.8, t, y)
    past = (t > edge - 1.0) & ((y - 0.5 * (before + after)) * np.sign(after - before) > 0)
    return t[np.flatnonzero(past)[0]]


def test_a_crosswind_step_edge_is_earlier_and_centred_when_smoothed(sample):
    """The sample's 800 N step at 5 s: the causal estimate crosses half of it tens of ms late; the
    smoothed one within a few steps of the edge (a wrong sign or a lag would put it later than the
    causal one), and the smoothed error after 2 s is smaller."""
    _, res = sample
    tr = np.genfromtxt(TRUTH, delimiter=",", names=True)
    t0 = 1.7e9
    t = res.t_ns * 1e-9 - t0
    edge = 5.0
    t_causal = _half_time(t, res.fw, edge)
    t_smooth = _half_time(t, res.smooth[:, S.S_FW], edge)
    assert t_causal - edge > 0.04
    assert abs(t_smooth - edge) < 0.02
    ok = (res.status & VALID) != 0
    sel = ok & (t >= t[ok][0] + 2.0)
    fw_true = np.interp(t, tr["t"] - t0, tr["Fw"])
    mw_true = np.interp(t, tr["t"] - t0, tr["Mw"])

    def err(y, ref):
        return np.sqrt(np.mean((y[sel] - ref[sel]) ** 2))

    assert err(res.smooth[:, S.S_FW], fw_true) < 0.7 * err(res.fw, fw_true)
    assert err(res.smooth[:, S.S_MW], mw_true) < 0.7 * err(res.mw, mw_true)


# ----------------------------------------------------------------- the CLI


def _read_csv(path: Path) -> tuple[list[str], np.ndarray]:
    with path.open() as fh:
        head = next(csv.reader(fh))
    return head, np.genfromtxt(path, delimiter=",", skip_header=1)


def test_cli_smooth_csv_and_mcap(tmp_path, capsys):
    base = ["replay", str(SAMPLE), "--vehicle", str(SAMPLE_VEHICLE), "--backend", "float", "-q"]
    assert main([*base, "--csv", str(tmp_path / "c.csv")]) == 0
    assert (
        main([*base, "--csv", str(tmp_path / "s.csv"), "--mcap", str(tmp_path / "s.mcap"), "--smooth"]) == 0
    )
    head_c, causal = _read_csv(tmp_path / "c.csv")
    head_s, smooth = _read_csv(tmp_path / "s.csv")
    n_est = len(CSV_COLUMNS)
    status_names = [c for c, _, _ in STATUS_COLUMNS]
    assert head_c == [c for c, _, _ in CSV_COLUMNS] + status_names
    # the smoothed columns after the estimate columns, the decoded status last (positions only append)
    assert head_s == head_c[:n_est] + SMOOTH_NAMES + status_names
    np.testing.assert_array_equal(smooth[:, :n_est], causal[:, :n_est])  # the causal columns unchanged
    np.testing.assert_array_equal(smooth[:, -len(status_names) :], causal[:, n_est:])
    fw_s = smooth[:, head_s.index("Fw_smooth")]
    assert np.isfinite(fw_s).all() and not np.array_equal(fw_s, smooth[:, head_s.index("Fw")])
    m = McapLog(tmp_path / "s.mcap")
    topic = m.json("/lde/smooth")
    assert len(topic["log_time"]) == len(smooth)
    for name in SMOOTH_NAMES:
        np.testing.assert_allclose(np.asarray(topic[name], float), smooth[:, head_s.index(name)], atol=1e-9)


def test_cli_smooth_with_the_fixed_backend_says_what_is_smoothed(tmp_path, capsys):
    rc = main(
        [
            "replay",
            str(SAMPLE),
            "--vehicle",
            str(SAMPLE_VEHICLE),
            "--csv",
            str(tmp_path / "f.csv"),
            "--smooth",
        ]
    )
    err = capsys.readouterr().err
    assert rc == 0
    assert "--smooth with backend fixed: the *_smooth columns are the float lateral filter's" in err
    head, rows = _read_csv(tmp_path / "f.csv")
    n_est = len(CSV_COLUMNS)
    assert head[n_est : n_est + len(SMOOTH_NAMES)] == SMOOTH_NAMES  # after the estimate columns


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--backend", "paper", "--csv", "X"], "--smooth smooths the lateral filter"),
        ([], "--smooth writes its columns to --csv and/or --mcap"),
    ],
)
def test_cli_smooth_errors_are_one_line(tmp_path, capsys, args, message):
    args = [str(tmp_path / "o.csv") if a == "X" else a for a in args]
    assert main(["replay", str(SAMPLE), "--smooth", "-q", *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("lde: error:") and message in err[0]
    assert not (tmp_path / "o.csv").exists()


@pytest.mark.slow
def test_cli_smooth_with_jobs_gives_the_sequential_files(tmp_path, capsys):
    """--smooth runs in each job: on a local Dask cluster the same files as one after the other."""
    logs = []
    frames = read_log(SAMPLE).frames
    from lde.io import write_candump

    for name, part in (("a.log", frames), ("b.log", frames[len(frames) // 3 :])):
        write_candump(tmp_path / name, part)
        logs.append(str(tmp_path / name))
    base = ["replay", *logs, "--vehicle", str(SAMPLE_VEHICLE), "--backend", "float", "--smooth", "-q"]
    assert main([*base, "--csv", str(tmp_path / "seq")]) == 0
    assert main([*base, "--csv", str(tmp_path / "par"), "--jobs", "2"]) == 0
    for name in ("a.csv", "b.csv"):
        seq = (tmp_path / "seq" / name).read_bytes()
        assert seq == (tmp_path / "par" / name).read_bytes()
        assert b"Fw_smooth" in seq.splitlines()[0]
