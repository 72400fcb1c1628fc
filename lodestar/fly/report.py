"""The twin's outputs: the telemetry of every step as CSV and JSON, a plot (attitude error,
executive state and status timeline, MCU milliseconds per step, faults marked) and the
summary text; every file written whole or not at all (``ground.files.write_atomic``)."""

import csv
import io
import json
from pathlib import Path

from lodestar.firmware import executive
from lodestar.ground.files import write_atomic

COLUMNS = ("index", "t_s", "status", "mode", "error_arcsec", "mcu_ms", "records", "faults",
           "frame", "solve", "level", "wrong")
"""CSV columns (``faults`` joined by ``+``; ``frame``: the sensor frame the packet came
from; ``solve``: the pipeline's mode, ``lost_in_space`` or ``tracking``)."""
JSON_KEYS = ("index", "t_s", "status", "mode", "error_arcsec", "mcu_ms", "records", "faults",
             "reported", "reported_error_arcsec", "sigma_cross_arcsec", "sigma_roll_arcsec",
             "beyond_5sigma", "beyond_180")
"""Per step in the JSON: the frame's own (``error_arcsec`` of an ``OK`` frame) and the
attitude the executive reported (``reported``: None, ``frame`` or ``fused``; its error per
axis, its sigmas, and issue 33's wrong: ``beyond_5sigma``, ``beyond_180``)."""


def document(rows, summary, engine, mcu, meta):
    """The ``--json`` object: ``engine``, ``mcu``, ``frames`` (per step the keys of
    :data:`JSON_KEYS`, plus ``frame``), the summary and the run's settings."""
    frames = [dict({k: r[k] for k in JSON_KEYS}, frame=r["frame"], solve=r["solve"])
              for r in rows]
    return dict(meta, engine=engine, mcu=mcu, frames=frames, summary=summary)


def csv_text(rows):
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(COLUMNS)
    for r in rows:
        writer.writerow(["+".join(r[c]) if c == "faults" else
                         ("" if r[c] is None else r[c]) for c in COLUMNS])
    return out.getvalue()


def plot_png(rows, title):
    """The run's figure as PNG bytes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = [r["t_s"] for r in rows]
    fig, axes = plt.subplots(3, 1, figsize=(10, 8), sharex=True)
    err = [(r["t_s"], r["error_arcsec"]) for r in rows if r["error_arcsec"] is not None]
    if err:
        axes[0].plot(*zip(*err), "o-", ms=3, label="reported attitude")
    axes[0].axhline(60.0, color="red", lw=0.8, ls="--", label="wrong (60\")")
    axes[0].set_ylabel("error, arcsec")
    axes[0].set_yscale("symlog", linthresh=1.0)
    axes[0].legend(loc="upper right", fontsize=8)
    states = list(executive.STATE_NAMES)
    axes[1].step(t, [states.index(r["mode"]) for r in rows], where="post", label="state")
    bad = [(r["t_s"], states.index(r["mode"])) for r in rows
           if r["status"] not in ("OK", "NO_FRAME")]
    if bad:
        axes[1].plot(*zip(*bad), "x", color="orange", label="frame not solved")
    axes[1].set_yticks(range(len(states)), states, fontsize=8)
    axes[1].legend(loc="upper right", fontsize=8)
    axes[2].bar(t, [r["mcu_ms"] for r in rows], width=0.02, color="gray")
    axes[2].set_ylabel("MCU ms per step\n(F401 estimate)")
    axes[2].set_xlabel("time, s")
    for r in rows:
        for name in r["faults"]:
            for ax in axes:
                ax.axvline(r["t_s"], color="purple", lw=0.8, alpha=0.6)
            axes[0].annotate(name, (r["t_s"], 1.0), fontsize=7, rotation=90,
                             color="purple")
    fig.suptitle(title)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    return buf.getvalue()


def write(out, rows, doc, title, parents=False):
    """``telemetry.csv``, ``telemetry.json`` and ``fly.png`` in folder ``out`` (made if
    missing; its parent must exist, as for every output the user names, unless
    ``parents``: the command's own default folder): the paths."""
    out = Path(out)
    out.mkdir(parents=parents, exist_ok=True)
    paths = [out / "telemetry.csv", out / "telemetry.json", out / "fly.png"]
    write_atomic(paths[0], csv_text(rows))
    write_atomic(paths[1], json.dumps(doc, indent=1))
    write_atomic(paths[2], plot_png(rows, title))
    return paths


def summary_text(s, engine, mcu, meta):
    """The summary lines the command prints."""
    lines = [f"lodestar fly: {meta['preset']} {meta['trajectory']} at "
             f"{' '.join(f'{w:g}' for w in meta['rate_deg_s'])} deg/s, {engine} gateware, "
             f"{mcu} MCU, {s['frames_played']} sensor frames in {s['steps']} steps",
             f"  first solve   step {s['first_solve_step']} at t = {s['first_solve_t_s']} s",
             f"  solved        {s['solved']} ({s['lost_in_space_solves']} lost in space, "
             f"{s['tracking_solves']} tracking), "
             f"availability after the first {100 * s['availability_after_first']:.1f} %",
             f"  wrong         {s['wrong']} (> 60\"); error max {_fmt(s['max_error_arcsec'])}\", "
             f"RMS {_fmt(s['rms_error_arcsec'])}\"",
             f"  reported      {s['reported']} ({s['reported_fused']} fused), availability "
             f"after the first {100 * s['reported_availability_after_first']:.1f} %, "
             f"beyond 5 sigma {s['reported_beyond_5sigma']}, beyond 180\" "
             f"{s['reported_beyond_180']}, error max {_fmt(s['reported_max_error_arcsec'])}\"",
             f"  MCU           {s['mcu_ms_mean']:.1f} ms per step (F401 estimate), "
             f"watchdog gap max {s['watchdog_max_gap_ms']} ms, {s['reboots']} resets"]
    for name, rec in s["recovery"].items():
        lines.append(f"  fault {name:15s} {rec['start_s']:.1f}-{rec['end_s']:.1f} s: back to "
                     f"tracking after {rec['frames_to_recovery']} frames "
                     f"(stated {rec['stated']}){'' if rec['within'] else ' NOT WITHIN'}")
    health = ", ".join(f"{k} {v}" for k, v in s["health"].items() if v)
    link = ", ".join(f"{k} {v}" for k, v in s["link"].items() if v)
    lines += [f"  health        {health}", f"  link          {link}"]
    return "\n".join(lines)


def _fmt(value):
    return "-" if value is None else f"{value:.2f}"
