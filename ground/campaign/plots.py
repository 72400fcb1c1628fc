"""Campaign plots (matplotlib, Agg backend, PNG): one function per study, taking the rows of
:mod:`lodestar.ground.campaign.tables` and returning the paths written.  Axes are labelled with
their units (deg/s, arcsec, px, V mag, %)."""

import io
import os

from lodestar.ground.campaign import tables, trials
from lodestar.ground.files import write_atomic


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _by(rows, *keys):
    groups = {}
    for row in rows:
        groups.setdefault(tuple(row[k] for k in keys), []).append(row)
    return groups


def _save(fig, path):
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, dpi=110, format="png")
    write_atomic(path, buf.getvalue())
    return path


def rate(rows, out_dir, title):
    """Availability (with the 95 % interval) and 1-sigma errors vs rate, per preset, with
    Dzamba's Table 4.1 and Schumann's 87 %: ``campaign_rate.png``."""
    plt = _pyplot()
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    for (preset,), group in _by(rows, "preset").items():
        r = [g["rate_deg_s"] for g in group]
        a = [g["availability_pct"] for g in group]
        # (clipped at 0: at 0 % or 100 % the Wilson bound equals the rate up to rounding)
        err = [[max(g["availability_pct"] - g["ci_low_pct"], 0.0) for g in group],
               [max(g["ci_high_pct"] - g["availability_pct"], 0.0) for g in group]]
        ax1.errorbar(r, a, yerr=err, marker="o", capsize=3, label=f"lodestar {preset}")
        for key, style in (("cross_1sigma", "-o"), ("roll_1sigma", "--s")):
            pts = [(g["rate_deg_s"], g[key]) for g in group if g[key] is not None]
            if pts:
                ax2.plot(*zip(*pts), style, label=f"{preset} {key.split('_')[0]}")
    dz = sorted(tables.DZAMBA_TABLE_4_1.items())
    ax1.plot([d[0] for d in dz], [d[1][1] for d in dz], "k^:",
             label="ST-16, Dzamba Table 4.1 (N >= 3)")
    ax1.plot([d[0] for d in dz], [d[1][0] for d in dz], "kv:", alpha=0.5,
             label="ST-16, Dzamba Table 4.1 (N >= 2)")
    ax1.plot([5.0], [tables.SCHUMANN_5DPS_PCT], "r*", markersize=12,
             label="Schumann: sky with >= 3 stars at 5 deg/s")
    ax1.set(xlabel="angular rate, deg/s", ylabel="solved correctly, % of attitudes",
            title=f"availability ({title})", ylim=(0, 102))
    ax1.grid(alpha=0.3)
    ax1.legend(fontsize=7, loc="lower left")
    ax2.set(xlabel="angular rate, deg/s", ylabel="1-sigma error, arcsec", yscale="log",
            title="accuracy (cross-boresight per axis, roll)")
    ax2.grid(alpha=0.3, which="both")
    ax2.legend(fontsize=7)
    return [_save(fig, os.path.join(out_dir, "campaign_rate.png"))]


def falsestars(rows, out_dir, title):
    """Success vs false stars and vs centroid noise per method and preset:
    ``campaign_falsestars.png``."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for ax, sweep, xlabel in ((axes[0], "false_stars", "false stars in the frame"),
                              (axes[1], "noise_px", "added centroid noise, px per axis")):
        for (preset, method), group in _by([r for r in rows if r["sweep"] == sweep],
                                           "preset", "method").items():
            ax.plot([g["level"] for g in group], [g["availability_pct"] for g in group],
                    "-o" if preset == "estcube2" else "--s", label=f"{preset} {method}")
            wrong = [(g["level"], g["availability_pct"]) for g in group if g["wrong"]]
            if wrong:
                ax.plot(*zip(*wrong), "rx", markersize=10)
        ax.set(xlabel=xlabel, ylabel="identified correctly, %", ylim=(0, 102))
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:             # a sweep may not have run
            ax.legend(fontsize=7)
    axes[0].set_title(f"false stars ({title}; red x: wrong solutions)")
    axes[1].set_title("centroid noise")
    return [_save(fig, os.path.join(out_dir, "campaign_falsestars.png"))]


def limiting(rows, out_dir, title):
    """Limiting magnitude vs rate (simulated 50 % detection, Eq 5.7, Schumann's model) and
    the detection curves: ``campaign_limiting.png``."""
    plt = _pyplot()
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    for (preset,), group in _by(rows, "preset").items():
        pts = [(g["rate_deg_s"], g["m50_sim"]) for g in group if g["m50_sim"] is not None]
        if pts:
            ax1.plot(*zip(*pts), "-o", label=f"{preset}: simulated, 50 % detected")
        ax1.plot([g["rate_deg_s"] for g in group], [g["eq57_m_t"] for g in group], ":",
                 label=f"{preset}: Dzamba Eq 5.7 (1/4 restored)")
        for g in group:
            if g["curve"]:
                m, t, f = zip(*g["curve"])
                ax2.plot(m, [b / a for a, b in zip(t, f)], label=f"{preset} {g['rate_deg_s']:g}")
    rates = sorted({g["rate_deg_s"] for g in rows if g["rate_deg_s"] > 0})
    ax1.plot(rates, [tables.schumann_limiting_magnitude(r) for r in rates], "k--",
             label="Schumann spin model, r = 1000 px")
    ax1.set(xlabel=f"angular rate, deg/s ({title})", ylabel="limiting magnitude, V",
            title="limiting magnitude vs rate")
    ax1.grid(alpha=0.3)
    ax1.legend(fontsize=7)
    ax2.set(xlabel="V magnitude", ylabel="fraction detected", title="detection curves",
            xlim=(trials.LIMITING_MAG_RANGE[0] + 2, trials.LIMITING_MAG_RANGE[1]))
    ax2.grid(alpha=0.3)
    ax2.legend(fontsize=6, ncol=2)
    return [_save(fig, os.path.join(out_dir, "campaign_limiting.png"))]


def accuracy(rows, out_dir, title):
    """Measured 1-sigma errors and the firmware's reported sigmas vs stars kept:
    ``campaign_accuracy.png``."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    for (preset,), group in _by(rows, "preset").items():
        for axis, colour in (("cross", "C0"), ("roll", "C1")):
            pts = [(g["stars_kept"], g[f"{axis}_1sigma"], g[f"sigma_{axis}_rms"])
                   for g in group if g[f"{axis}_1sigma"] is not None]
            if not pts:
                continue
            n, measured, reported = zip(*pts)
            style = "-" if preset == "estcube2" else "-."
            ax.plot(n, measured, style + "o", color=colour, label=f"{preset} {axis} measured")
            ax.plot(n, reported, style, color=colour, alpha=0.5,
                    label=f"{preset} {axis} Shuster (reported)")
    ax.set(xlabel="brightest records kept", ylabel="1-sigma error, arcsec", yscale="log",
           title=f"accuracy vs stars ({title})")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    return [_save(fig, os.path.join(out_dir, "campaign_accuracy.png"))]


def fov(rows, out_dir, title):
    """Availability (with the 95 % interval; red x: wrong solutions) and 1-sigma errors vs
    horizontal FOV, per preset sensor: ``campaign_fov.png``."""
    plt = _pyplot()
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    for (preset,), group in _by(rows, "preset").items():
        f = [g["fov_deg"] for g in group]
        a = [g["availability_pct"] for g in group]
        err = [[max(g["availability_pct"] - g["ci_low_pct"], 0.0) for g in group],
               [max(g["ci_high_pct"] - g["availability_pct"], 0.0) for g in group]]
        ax1.errorbar(f, a, yerr=err, marker="o", capsize=3, label=f"lodestar, {preset} sensor")
        wrong = [(g["fov_deg"], g["availability_pct"]) for g in group if g["wrong"]]
        if wrong:
            ax1.plot(*zip(*wrong), "rx", markersize=10, label="wrong solutions")
        for key, style in (("cross_1sigma", "-o"), ("roll_1sigma", "--s")):
            pts = [(g["fov_deg"], g[key]) for g in group if g[key] is not None]
            if pts:
                ax2.plot(*zip(*pts), style, label=f"{preset} {key.split('_')[0]}")
    ax1.axhline(99.0, color="k", ls=":", lw=1, label="goal 99 %")
    low = min([g["ci_low_pct"] for g in rows if g["ci_low_pct"] is not None] + [99.0])
    ax1.set(xlabel="horizontal FOV, deg", ylabel="solved correctly, % of attitudes",
            title=f"availability at rest ({title})", ylim=(max(0.0, low - 5.0), 101))
    ax1.grid(alpha=0.3)
    ax1.legend(fontsize=7, loc="lower left")
    ax2.set(xlabel="horizontal FOV, deg", ylabel="1-sigma error, arcsec", yscale="log",
            title="accuracy (cross-boresight per axis, roll)")
    ax2.grid(alpha=0.3, which="both")
    ax2.legend(fontsize=7)
    return [_save(fig, os.path.join(out_dir, "campaign_fov.png"))]


PLOTS = {"rate": rate, "falsestars": falsestars, "limiting": limiting, "accuracy": accuracy,
         "fov": fov}
