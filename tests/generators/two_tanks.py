"""Records of a cascade of two tanks, written from the physics (not from the package's
code): a pump fills an upper tank through its inflow, the upper tank drains through an
orifice into a lower tank, which drains through its own orifice; the upper tank overflows
at its rim, part of the spill falling into the lower tank. The level sensor reads the lower
tank in volts, with noise, and saturates at its range. Continuous time, integrated with
``substeps`` explicit Euler steps per sample (the sampled record is not the one-step
recursion any model of the package uses).

    A1 dh1/dt = kp p(t) - c1 sqrt(2 g h1) - spill
    A2 dh2/dt = c1 sqrt(2 g h1) - c2 sqrt(2 g h2) + share * spill

``spill`` keeps ``h1 <= rim``. Output ``y = sensor_gain * h2 + sensor_offset + noise``,
clipped at ``sensor_max`` when given.
"""

from __future__ import annotations

import numpy as np

G = 9.81


def random_tanks(rng, *, overflow=True, clip=True):
    """Random plant parameters: areas, orifices and pump gain give time constants of tens
    to hundreds of samples at the sample time ``dt``."""
    area1, area2 = rng.uniform(0.5, 2.0, 2) * 1e-2         # m^2
    c1, c2 = rng.uniform(0.5, 2.0, 2) * 1e-5                # m^2 (orifice x discharge)
    pump = rng.uniform(0.6, 1.4) * 1e-5                     # m^3/s per volt
    # the rim at the level a steady pump voltage of 4.5-7 V holds: the upper tank overflows
    # only on the highest plateaus
    rim = (pump * rng.uniform(4.5, 7.0) / c1) ** 2 / (2 * G)
    return {"area1": area1, "area2": area2, "c1": c1, "c2": c2, "pump": pump,
            "rim": rim if overflow else np.inf,
            "share": rng.uniform(0.2, 0.8),
            "sensor_gain": rng.uniform(15.0, 30.0),          # V/m
            "sensor_offset": rng.uniform(-0.5, 0.5),
            "clip": clip, "dt": 4.0, "substeps": 8}


def pump_voltage(rng, n, kind="plateaus"):
    """A positive pump voltage: random plateaus with a slow sine, or a multisine, 1-9 V."""
    t = np.arange(n)
    if kind == "plateaus":
        lengths = rng.integers(40, 250, size=n // 40 + 2)
        p = np.repeat(rng.uniform(2.0, 8.0, size=len(lengths)), lengths)[:n]
        return np.clip(p + rng.uniform(0.5, 1.5) * np.sin(2 * np.pi * t / rng.uniform(300, 900)),
                       1.0, 9.0)
    period = int(rng.integers(300, 900))
    ks = np.r_[1, rng.choice(np.arange(2, 8), size=3, replace=False)]
    s = sum(np.cos(2 * np.pi * k * t / period + rng.uniform(0, 2 * np.pi)) for k in ks)
    return 5.0 + 3.5 * s / np.max(np.abs(s))


def simulate_tanks(plant, p, rng, noise_frac=0.01):
    """Sensor record of the lower tank for pump voltage ``p``; the tanks start at the
    levels a constant first voltage would hold. Returns ``(y, levels)``."""
    dt = plant["dt"] / plant["substeps"]
    q_in = plant["pump"] * p[0]
    # equilibrium for the first voltage (each orifice passes the inflow)
    h1 = min((q_in / plant["c1"]) ** 2 / (2 * G), plant["rim"])
    h2 = (q_in / plant["c2"]) ** 2 / (2 * G)
    levels = np.empty((len(p), 2))
    for t, p_t in enumerate(p):
        levels[t] = h1, h2
        for _ in range(plant["substeps"]):
            out1 = plant["c1"] * np.sqrt(2 * G * max(h1, 0.0))
            out2 = plant["c2"] * np.sqrt(2 * G * max(h2, 0.0))
            h1_new = h1 + dt * (plant["pump"] * p_t - out1) / plant["area1"]
            spill = max(h1_new - plant["rim"], 0.0) * plant["area1"]   # m^3 this substep
            h1 = h1_new - spill / plant["area1"]
            h2 = h2 + (dt * (out1 - out2) + plant["share"] * spill) / plant["area2"]
    y = plant["sensor_gain"] * levels[:, 1] + plant["sensor_offset"]
    y = y + noise_frac * np.ptp(y) * rng.normal(size=len(y))
    if plant["clip"]:
        top = np.quantile(y, 0.97)  # the sensor's range sits just under the highest levels
        y = np.minimum(y, top)
    return y, levels
