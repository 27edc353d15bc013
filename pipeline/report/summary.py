"""The summary box at the top of the report: one verdict per output with the size of the evidence (trials,
minutes, usable share), the best model per output (``pipeline.report.verdicts``, the same choice as
``reports/headline.json``), the models that failed or whose band misses its coverage, and what was left out."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from pipeline.report import html as H
from pipeline.report.studies import OUTPUT_LABELS, Part, dof_key, label


@dataclass
class Evidence:
    """How much data stands behind the verdicts: trials synced, their minutes, the share usable for fitting."""
    trials: int = 0
    minutes: float = 0.0
    usable: float | None = None  # the smoother's usable share of the grid (or sync's segments), sample-weighted
    test_trials: list[str] = field(default_factory=list)

    def text(self) -> str:
        if not self.trials:
            return "no synced trial"
        test = f", {len(self.test_trials)} of them unseen ({', '.join(self.test_trials)})" if self.test_trials else ""
        usable = "" if self.usable is None else f", {self.usable:.0%} usable"
        return f"{self.trials} trial(s){test}, {self.minutes:.1f} min{usable}"


def _fit(r2: float) -> str:
    """A word for the best model's R² on the unseen trial; below 0 it says so (worse than predicting the mean)."""
    if r2 < 0:
        return "worse than the mean there: no model to trust on this output"
    return ("good" if r2 >= 0.9 else "fair" if r2 >= 0.7 else "weak" if r2 >= 0.3 else "poor")


def verdict_lines(coupled_part: Part, decoupled_part: Part, sim_part: Part, evidence: Evidence | None) -> list[str]:
    """One line per output: the coupled outputs (best model, its R² on the unseen trial, a word for it) and the
    damping DOFs (best model, its MAE against least squares); each ends with the size of the evidence."""
    size = f" — evidence: {evidence.text()}" if evidence else ""
    lines = []
    best = {h["output"]: h for h in coupled_part.headline}
    for out in coupled_part.outputs:
        name = OUTPUT_LABELS.get(out, out)
        failed = [v for v in coupled_part.verdicts if f" on {name}" in v]
        if name in best:
            h = best[name]
            r2 = h["R² on the unseen trial"]
            lines.append(f"{name}: {h['best model']} is best, R² {r2:.3g} on the unseen trial ({_fit(r2)})"
                         + (f"; {len(failed)} model(s) failed there" if failed else "") + size)
        else:
            lines.append(f"{name}: no model to trust — every model failed or none was scored" + size)
    for h in sorted(decoupled_part.headline, key=lambda h: dof_key(h["dof"])):
        vs = "" if not h["ls"] else (f", {h['mae'] / h['ls']:.2f}× least squares'" if h["model"] != "ls"
                                     else ", least squares (the reference) itself")
        bands = [b for b in sim_part.bands if f" on {h['dof']} " in b]
        lines.append(f"damping d_{h['dof']}: {label(h['model'])} is best, CV MAE {h['mae']:.4g} {h['unit']}{vs}"
                     + (f"; {'; '.join(bands)}" if bands else "") + size)
    return lines


def headline(coupled_part: Part, decoupled_part: Part, sim_part: Part, quarantined: int, failed: int,
             protocol: str = "", evidence: Evidence | None = None) -> str:
    """The box at the top: one verdict per output with the size of the evidence, best model per output, damping
    MAE vs LS, bridging vs hold-last (among the models that did not fail), what was left out, and the tuning
    protocol behind Tables II and III."""
    lines = verdict_lines(coupled_part, decoupled_part, sim_part, evidence)
    parts = ["<ul class='verdicts'>" + "".join(f"<li>{H.esc(v)}</li>" for v in lines) + "</ul>"] if lines else []
    parts += [f"<p>{H.esc(protocol)}</p>"] if protocol else []
    if coupled_part.headline:
        parts.append(H.table(coupled_part.headline, caption="Best coupled model per output: R² on the unseen "
                                                            "trial (Table III's final check)"))
    if decoupled_part.headline:
        parts.append(H.table([{"DOF": h["dof"], "best damping model": label(h["model"]),
                               "CV test MAE": f"{h['mae']:.4g} {h['unit']}",
                               "LS (reference)": "—" if h["ls"] is None else f"{h['ls']:.4g} {h['unit']}",
                               "vs LS": f"{h['mae'] / h['ls']:.2f}×" if h["ls"] else "—"}
                              for h in sorted(decoupled_part.headline, key=lambda h: dof_key(h["dof"]))],
                             caption="Damping models (paper 001): per DOF the lowest CV test MAE among all models, "
                                     "least squares (the reference) included, and LS's beside it"))
    parts += [f"<p>{H.esc(line)}</p>" for line in decoupled_part.buoyancy]
    parts += [f"<p class='muted'>{H.esc(what)} skipped: {H.esc(p.skipped)}.</p>"
              for what, p in (("Coupled models (paper 000)", coupled_part), ("Free runs", sim_part)) if p.skipped]
    failures = coupled_part.verdicts + decoupled_part.verdicts + sim_part.verdicts
    if failures:
        parts.append(f"<p class='warn'><b>Failed, left out of “best”:</b> {H.esc('; '.join(failures))}.</p>")
    if sim_part.bands:
        parts.append(f"<p class='warn'><b>Bands that miss their coverage</b> (the band, not the mean: marked, "
                     f"still ranked): {H.esc('; '.join(sim_part.bands))}.</p>")
    if sim_part.headline:
        best_b: dict[tuple[str, Any], dict[str, Any]] = {}
        for h in sim_part.headline:
            if h.get("failed"):
                continue  # diverged in a window (its mean is over the windows it survived) or failed a free run
            key = (h["trial"], h["outage [s]"])
            if key not in best_b or h["mean error [m]"] < best_b[key]["mean error [m]"]:
                best_b[key] = h
        parts.append(H.table([{"trial": t, "outage [s]": w, "best model": h["model"],
                               "mean error [m]": h["mean error [m]"], "vs hold-last": h["vs hold-last"]}
                              for (t, w), h in best_b.items()],
                             caption="DVL-outage bridging: the best model's position error against holding the "
                                     "last velocity"))
    left = (f"{quarantined} input(s) quarantined, {failed} model(s) failed to fit"
            if quarantined or failed else "Nothing was quarantined and every model fitted.")
    cls = "warn" if quarantined or failed else "muted"
    parts.append(f"<p class='{cls}'>{H.esc(left)} (see <a href='#quarantine'>Quarantine and failures</a>).</p>")
    return "<div class='box'>" + "".join(parts) + "</div>"
