"""Paired comparison of the tuning cut with the decisive spike against d290092.

``runs.csv`` holds the cut with the rule; ``runs-d290092.csv`` the 23 runs it changed, flown
again without it. Every other run declared the same channels at the same times: the same flight.
"""

import csv
import statistics

KINDS = ("zero", "stuck", "bias", "drift", "scale", "noise", "spikes")


def _true(value: str) -> bool:
    return value in ("True", "true", "1")


def _rows(path: str) -> dict[str, dict[str, str]]:
    with open(path, newline="") as f:
        return {r["run_id"]: r for r in csv.DictReader(f)}


def _summary(rows: dict[str, dict[str, str]]) -> str:
    """Within 1 s of observable (median delay) and named right, per kind; then the totals."""
    faulted = [r for r in rows.values() if r["fault"] != "none"]
    parts = []
    for kind in KINDS:
        seen = [r for r in faulted if (r["fault_kind"] or "zero") == kind and r["observable_t_s"]]
        within = sum(_true(r["identified_within_1s"]) for r in seen)
        delays = [
            float(r["detection_delay_s"])
            for r in seen
            if r["detection_delay_s"] and _true(r["identified_ok"])
        ]
        named = sum(r["named_kind"] == kind for r in seen)
        parts.append(
            f"{kind} {within}/{len(seen)} ({statistics.median(delays):.2f} s) named {named}"
        )
    within = sum(_true(r["identified_within_1s"]) for r in faulted if r["observable_t_s"])
    lost = sum(r["status"] != "stable" for r in rows.values())
    return "; ".join(parts) + f"\n   within 1 s {within}, runs lost {lost}"


def main() -> None:
    """Print both summaries and every run whose declarations changed."""
    new = _rows("runs.csv")
    old = {**new, **_rows("runs-d290092.csv")}
    print("d290092:", _summary(old))
    print("with the rule:", _summary(new))
    for run_id, row in new.items():
        before = old[run_id]
        if row["declarations"] != before["declarations"]:
            print(
                f"  {run_id}: {before['declarations']} -> {row['declarations']}, named "
                f"{before['named_kind']} -> {row['named_kind']}, attitude MSE after "
                f"{before['est_att_mse_after_decl_deg2'][:6]} -> "
                f"{row['est_att_mse_after_decl_deg2'][:6]} deg2"
            )


if __name__ == "__main__":
    main()
