"""A campaign's figures: Fig. 2 and the IMM's detection delays.

Fig. 2 re-flies one run and plots its mode probabilities, as the paper's Fig. 2 does for a
q-gyro failure; the delay plot shows each channel's detection delay by air.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

from immukf_sitl.estimation.fault_modes import single_fault_modes
from immukf_sitl.experiments.campaign import Campaign
from immukf_sitl.experiments.campaign_run import fly
from immukf_sitl.experiments.campaign_summary import (
    MATRIX_WITHIN_S,
    _float,
    _ordered,
)
from immukf_sitl.experiments.report import plot_summary
from immukf_sitl.experiments.tables import (
    Row,
)


def write_figure(campaign: Campaign, path: Path) -> str | None:
    """Re-fly the campaign's figure run and plot its mode probabilities (the paper's Fig. 2).

    Returns
    -------
    str or None
        What the figure shows, or ``None`` when the campaign has no such run.
    """
    spec = campaign.figure_run()
    if spec is None:
        return None
    run, monitor = fly(spec)
    summary = run.summary()
    t, probabilities = run.history.probability_series([m.name for m in single_fault_modes()])
    plot_summary(str(path), summary, t, probabilities, run.truth, run.history.track())
    detections = ", ".join(f"{e.mode.name} at {e.t_s:.2f} s" for e in summary.detections)
    zeroed = f"the {spec.mode.name} channel(s) zeroed at {spec.fault_t_s:g} s"
    if spec.second_fault is not None:  # a pair run: each channel at its own time
        first = spec.mode.channels[0]
        zeroed = f"{first} zeroed at {spec.fault_t_s:g} s and {spec.second_fault} at "
        zeroed += f"{spec.second_t_s:g} s"
    return (
        f"{spec.variant} with {zeroed}, replicate 0, {spec.loop} loop: declarations "
        f"{detections or 'none'}; {monitor.reason or 'maintained flight'}"
    )


def plot_delays(rows: Sequence[Row], path: Path) -> None:
    """PNG: the IMM's detection delay by channel and air, one panel per filter model.

    Missed and wrongly identified faults are drawn as crosses above the axis's top.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [r for r in rows if r["status"] != "error" and r["variant"] == "imm"]
    models = _ordered([r["filter_model"] for r in rows]) or ["none"]
    airs = _ordered([r["air"] for r in rows])
    fig, axes = plt.subplots(1, len(models), figsize=(5.5 * len(models), 4), squeeze=False)
    channels = ("x", "y", "z", "p", "q", "r")
    top = 3.0
    for ax, model in zip(axes[0], models, strict=True):
        for k, air in enumerate(airs):
            offset = (k - (len(airs) - 1) / 2) * 0.2
            good_x, good_y, bad_x = [], [], []
            for r in rows:
                if r["filter_model"] != model or r["air"] != air or r["fault"] not in channels:
                    continue
                if r["observable_t_s"] == "":
                    continue
                x = channels.index(r["fault"]) + offset
                delay = _float(r["detection_delay_s"])
                if r["identified_ok"] == "true" and math.isfinite(delay):
                    good_x.append(x)
                    good_y.append(min(delay, top))
                else:
                    bad_x.append(x)
            color = f"C{k}"
            ax.scatter(good_x, good_y, color=color, label=air, s=22)
            ax.scatter(bad_x, [top * 1.05] * len(bad_x), color=color, marker="x", s=30)
        ax.axhline(MATRIX_WITHIN_S, color="black", lw=0.8, ls="--")
        ax.set_xticks(range(len(channels)), channels)
        ax.set_ylim(-0.1, top * 1.12)
        ax.set_xlabel("zeroed channel")
        ax.set_ylabel(f"delay from observability (s; > {top:g} at {top:g}); × not identified")
        ax.set_title(f"IMM detection delay, filter model {model}")
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
