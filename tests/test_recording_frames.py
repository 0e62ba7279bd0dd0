"""Recordings like MATLAB's iddata: frames in and out, split, detrend, decimate, plot, and
estimators taking a Recording or a DataFrame."""

import matplotlib

matplotlib.use("Agg")

import jax  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

import hbjax  # noqa: E402
import hbjax.plot  # noqa: E402

pd = pytest.importorskip("pandas")


def _frame(n=400, dt=0.25):
    rng = np.random.default_rng(0)
    return pd.DataFrame(
        {"uEst": rng.standard_normal(n), "yEst": rng.standard_normal(n),
         "velocity": np.arange(n, dtype=float), "label": ["x"] * n},
        index=pd.Index(10.0 + dt * np.arange(n), name="t"))


def test_dataframe_round_trip_keeps_times_and_channels():
    df = _frame()
    rec = hbjax.Recording.from_dataframe(df, input="uEst", output="yEst")
    assert rec.dt == pytest.approx(0.25) and rec.t0 == pytest.approx(10.0)
    assert list(rec.channels) == ["velocity"]  # numeric columns only
    np.testing.assert_array_equal(rec.v, df["uEst"].to_numpy())
    np.testing.assert_allclose(rec.t, df.index.to_numpy())
    back = rec.to_dataframe()
    assert list(back.columns) == ["v", "y", "velocity"] and back.index.name == "t"
    again = hbjax.Recording.from_dataframe(back, input="v", output="y")
    assert again.dt == pytest.approx(rec.dt) and again.t0 == pytest.approx(rec.t0)
    np.testing.assert_array_equal(again.channels["velocity"], rec.channels["velocity"])
    plain = hbjax.Recording.from_dataframe(df.reset_index(drop=True), input=0, output=1,
                                           channels={"speed": "velocity"})
    assert plain.dt is None and list(plain.channels) == ["speed"]
    assert plain.to_dataframe().index.name == "sample"
    timed = hbjax.Recording.from_dataframe(df.reset_index(), input="uEst", output="yEst",
                                           time="t", channels=[])
    assert timed.dt == pytest.approx(0.25) and not timed.channels
    with pytest.raises(ValueError, match="no input column 'u'"):
        hbjax.Recording.from_dataframe(df, input="u", output="yEst")


def test_channels_are_checked():
    with pytest.raises(ValueError, match="channel 'f' must hold 3 samples"):
        hbjax.Recording(np.zeros(3), np.zeros(3), channels={"f": np.zeros(4)})
    with pytest.raises(ValueError, match="channel 'f' contains NaN"):
        hbjax.Recording(np.zeros(3), np.zeros(3), channels={"f": [0, np.nan, 1]})
    # as `v` and `y`: never a cast to the real part or a parse of text
    with pytest.raises(TypeError, match="channel 'f' must be real"):
        hbjax.Recording(np.zeros(3), np.zeros(3), channels={"f": np.arange(3) + 5j})
    with pytest.raises(TypeError, match="channel 'f' must be a numeric array"):
        hbjax.Recording(np.zeros(3), np.zeros(3), channels={"f": np.array(["1", "2", "3"])})
    with pytest.raises(TypeError, match="channel 'f' must be a numeric array, got str"):
        hbjax.Recording(np.zeros(3), np.zeros(3), channels={"f": "abc"})
    rec = hbjax.Recording(np.zeros(3), np.zeros(3), channels={"f": [0, 1, 2]})
    with pytest.raises(TypeError):
        rec.channels["g"] = np.zeros(3)


def test_split_keeps_time_axis_and_channels():
    rec = hbjax.Recording.from_dataframe(_frame(), input="uEst", output="yEst")
    est, val = rec.split(0.75)
    assert (len(est), len(val)) == (300, 100)
    assert val.t[0] == pytest.approx(rec.t[300]) and val.dt == rec.dt
    np.testing.assert_array_equal(np.concatenate([est.y, val.y]), rec.y)
    np.testing.assert_array_equal(val.channels["velocity"], rec.channels["velocity"][300:])
    first, last = rec.split(-40)
    assert len(last) == 40 and last.t[-1] == pytest.approx(rec.t[-1])
    for bad in (0.0, 1.0, 0, 400):
        with pytest.raises(ValueError):
            rec.split(bad)
    part = rec.slice(100, 110)
    assert part.t[0] == pytest.approx(rec.t[100]) and len(part.channels["velocity"]) == 10


def test_detrend_removes_a_line_and_keeps_it():
    t = 0.1 * np.arange(500)
    wiggle = np.sin(2 * np.pi * np.arange(500) / 50)  # whole periods: zero mean, no slope
    rec = hbjax.Recording(3.0 - 0.5 * t + wiggle, 2.0 + 0.25 * t, dt=0.1)
    lin = rec.detrend("linear")
    assert np.max(np.abs(lin.y)) < 1e-12
    assert lin.trend.y_offset == pytest.approx(2.0) and lin.trend.y_slope == pytest.approx(0.25)
    assert lin.trend.v_slope == pytest.approx(-0.5, abs=0.01)
    np.testing.assert_allclose(lin.trend.restore(lin).v, rec.v, atol=1e-12)
    mean = rec.detrend()
    assert abs(np.mean(mean.v)) < 1e-12 and mean.trend.kind == "mean"
    both = mean.detrend("linear")  # trends add up
    assert both.trend.y_slope == pytest.approx(0.25) and both.trend.kind == "linear"
    np.testing.assert_allclose(both.trend.restore(both).y, rec.y, atol=1e-12)
    with pytest.raises(ValueError, match="'mean' or 'linear'"):
        rec.detrend("quadratic")


def test_decimate_filters_aliases_and_matches_scipy_fir():
    signal = pytest.importorskip("scipy.signal")
    n, k = 4000, 4
    x = np.random.default_rng(1).standard_normal(n)
    rec = hbjax.Recording(x, x, dt=0.01, channels={"c": x})
    dec = rec.decimate(k)
    assert len(dec) == n // k and dec.dt == pytest.approx(0.04)
    ref = signal.decimate(x, k, ftype="fir")  # same filter design, zero-padded ends
    np.testing.assert_allclose(dec.v[30:-30], ref[30:-30], atol=1e-12)
    np.testing.assert_array_equal(dec.channels["c"], dec.v)
    step = np.arange(n)
    low = np.sin(2 * np.pi * 0.02 * step)  # well below the new Nyquist (0.125 cycles/sample)
    high = np.sin(2 * np.pi * 0.3 * step)  # would alias to 0.05 without the filter
    out = hbjax.Recording(low + high, np.ones(n)).decimate(k)
    np.testing.assert_allclose(out.v[50:-50], low[::k][50:-50], atol=0.01)
    np.testing.assert_allclose(out.y, 1.0, atol=1e-12)  # constants survive up to the ends
    for length in (10, 23, 40, 60):  # shorter than the filter: reflected again and again
        ramp = 0.5 + 0.25 * np.arange(length)
        short = hbjax.Recording(ramp, ramp).decimate(5)
        np.testing.assert_allclose(short.v, ramp[::5], atol=1e-12)
    with pytest.raises(ValueError, match="positive integer"):
        rec.decimate(0)


def test_plot_axes_in_seconds_when_dt_known():
    rec = hbjax.Recording.from_dataframe(_frame(), input="uEst", output="yEst")
    axes = rec.plot()
    assert len(axes) == 3 and axes[-1].get_xlabel() == "time (s)"
    assert axes[0].get_lines()[0].get_xdata()[-1] == pytest.approx(rec.t[-1])
    axes = hbjax.plot.plot_recording(hbjax.Recording(rec.v, rec.y), channels=False)
    assert len(axes) == 2 and axes[-1].get_xlabel() == "sample"
    ax = hbjax.plot.plot_output(rec.y, rec.y, dt=0.5)
    assert ax.get_xlabel() == "time (s)" and ax.get_lines()[0].get_xdata()[-1] == 0.5 * 399


def test_the_diagnosis_figure_keeps_the_recordings_times():
    c = hbjax.concealed_recording("output_saturation", n=1200, key=jax.random.key(0))
    _, late = hbjax.Recording(c.v, c.y, dt=0.01).split(0.5)  # starts at t0 = 6 s
    d = hbjax.diagnose(c.model, late, effects=["output_saturation"], progress=False)
    ax = np.ravel(hbjax.plot.plot_diagnosis(d))[0]
    np.testing.assert_allclose(ax.get_lines()[0].get_xdata()[[0, -1]], late.t[[0, -1]])


def test_estimators_take_recordings_and_dataframes(system):
    v = np.asarray(jax.random.uniform(jax.random.key(3), (800,), minval=-2.0, maxval=2.0))
    y = np.asarray(hbjax.simulate(system, v, 0.01 * jax.random.normal(jax.random.key(4), (800,))))
    df = pd.DataFrame({"uEst": v, "yEst": y, "other": y})
    theta = hbjax.flatten_params(hbjax.refine(system, (v, y)).model)
    rec = hbjax.Recording.from_dataframe(df, input="uEst", output="yEst", dt=0.1)
    for data in (rec, df[["uEst", "yEst"]]):
        got = hbjax.flatten_params(hbjax.refine(system, data).model)
        np.testing.assert_allclose(got, theta, rtol=1e-9, atol=1e-12)
    # a list mixes recordings and pairs, each checked as one record
    with pytest.raises(ValueError, match=r"in `recordings\[1\]`, v has 10 samples"):
        hbjax.refine(system, [rec, (v[:10], y)])
    fit_df = hbjax.fit(df[["uEst", "yEst"]], na=2, nb=2, m=3, key=jax.random.key(0), starts=4)
    fit_arr = hbjax.fit((v, y), na=2, nb=2, m=3, key=jax.random.key(0), starts=4)
    np.testing.assert_allclose(hbjax.flatten_params(fit_df.model),
                               hbjax.flatten_params(fit_arr.model), rtol=1e-9, atol=1e-12)
    with pytest.raises(ValueError, match="must have 2 columns"):
        hbjax.refine(system, df)
    # diagnose unpacks the recording (and then finds it too short to hold out 30%)
    with pytest.raises(ValueError, match="record too short"):
        hbjax.diagnose(system, rec.slice(0, 120), progress=False)
    with pytest.raises(TypeError, match="`y` is missing"):
        hbjax.diagnose(system, v, progress=False)


def test_brfd_recordings_carry_velocity_and_actuator_forces():
    for name in hbjax.datasets.brfd_names():
        rec = hbjax.datasets.brfd(name)
        assert list(rec.channels) == ["velocity", "actuator force 1", "actuator force 2"]
        # the velocity channel is the time derivative of the displacement input (in/s)
        slope = np.gradient(rec.v, rec.dt)
        assert np.corrcoef(slope, rec.channels["velocity"])[0, 1] > 0.99
        assert np.std(rec.channels["velocity"]) / np.std(slope) == pytest.approx(1.0, abs=0.01)


def test_dataframe_round_trip_keeps_the_exact_sampling_period():
    # The index holds t0 + k dt rounded; its steps are dt only up to rounding (0.1 came
    # back as 0.10000000000000009). The frame carries the period itself.
    for dt in (0.1, 0.01, 1 / 3, 7e-3):
        rec = hbjax.Recording(np.arange(1000.0) % 7, np.arange(1000.0) % 5, dt=dt, t0=2.5)
        back = hbjax.Recording.from_dataframe(rec.to_dataframe(), input="v", output="y")
        assert back.dt == dt and back.t0 == 2.5
    # a frame whose index was resampled afterwards keeps its own spacing
    frame = rec.to_dataframe().iloc[::2]
    assert hbjax.Recording.from_dataframe(frame, input="v", output="y").dt == pytest.approx(2 * dt)


def test_estimate_initial_state_takes_a_recording(system):
    model = system
    v = np.repeat(np.random.default_rng(0).uniform(-8, 8, 40), 10)
    y = np.asarray(hbjax.simulate(model, v, u0=1.0, y0=[0.5, -0.2]))
    rec = hbjax.Recording(v, y)
    a, b = hbjax.estimate_initial_state(model, rec), hbjax.estimate_initial_state(model, v, y)
    np.testing.assert_array_equal(np.asarray(a.y0), np.asarray(b.y0))
    assert float(a.u0) == float(b.u0)


def test_decimating_a_detrended_record_without_dt_restores_the_same_trend():
    """Without dt the time axis counts samples, and the decimated record counts its own:
    the removed trend is carried over to that axis (restoring it was 5.9 off)."""
    k = np.arange(400.0)
    rec = hbjax.Recording(0.01 * k + np.sin(k / 9), 3 - 0.02 * k + np.cos(k / 7)).slice(40)
    for kind in ("mean", "linear"):
        kept = rec.detrend(kind).decimate(4)
        np.testing.assert_allclose(kept.trend.restore(kept).y, rec.decimate(4).y, atol=1e-12)
        np.testing.assert_allclose(kept.trend.restore(kept).v, rec.decimate(4).v, atol=1e-12)


def test_a_frame_keeps_its_output_and_its_sample_origin():
    clash = hbjax.Recording([1.0, 2.0], [3.0, 4.0], channels={"y": [7.0, 8.0]})
    with pytest.raises(ValueError, match="channel name 'y' is the frame's output column"):
        clash.to_dataframe()
    rec = hbjax.Recording(np.arange(100.0), np.arange(100.0) ** 0.5).slice(50)
    back = hbjax.Recording.from_dataframe(rec.to_dataframe(), input="v", output="y")
    assert back.t0 == 50.0 and back.dt is None
    np.testing.assert_array_equal(back.t, rec.t)


def test_line_styles_reach_every_panel():
    rec = hbjax.Recording(np.arange(50.0), np.arange(50.0), channels={"w": np.ones(50)})
    for kwargs in ({"lw": 3}, {"linewidth": 3}):
        axes = hbjax.plot.plot_recording(rec, **kwargs)
        assert [ax.lines[0].get_linewidth() for ax in axes] == [3.0, 3.0, 3.0]
    assert [ax.lines[0].get_linewidth() for ax in hbjax.plot.plot_recording(rec)] == [1.0] * 3
