"""Worked example: the whole gprm chain from Python, as a notebook user would run it.

Run it as a script (``.venv/bin/python docs/worked_example.py [OUT_DIR]``) or paste the cells
(``# %%``) into a notebook. It uses the library API only (no shell commands), small sizes so it
takes well under a minute, and writes a run directory that ``gprm report`` can read. The tests
execute it (tests/demo/test_worked_example.py).
"""

# %% Imports and where to write
import sys
import tempfile
from pathlib import Path

import numpy as np

OUT = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(tempfile.mkdtemp(prefix="gprm-example-"))
OUT.mkdir(parents=True, exist_ok=True)
print(f"writing to {OUT}")

# %% 1. Parameters: the paper's set (Table 2 constants, Table 3 best fit), SI inside
from gprm.params import REGISTRY, from_si, paper

ps = paper()
print("m2 =", from_si(ps.values["m2"], "m2"), REGISTRY["m2"].unit, "| fitted:", len(ps.fitted))

# %% 2. Simulate the tip retraction (Eq. 2 solved exactly; outputs of Eq. 3)
from gprm.simulate import simulate

sim = simulate(ps, piezo=2, t_end=1.2e-3, rate=200e3)
print("peak x_head: %.3f um" % (1e6 * np.abs(sim.outputs["x_head"]).max()))

# %% 3. A synthetic ground-test campaign with known truth, and its mean signals (Sec. 2)
from gprm.campaign import PreprocessOptions, run_preprocess
from gprm.campaign.files import read_tables, write_campaign, write_means
from gprm.campaign.synth import SynthConfig, synth_campaign

campaign = synth_campaign(seed=1, config=SynthConfig(nonlinear=False))   # faster variant
write_campaign(campaign, OUT / "campaign.nc")
# the stage's entry point with its default options: the 2-sigma crossing at 1.01 ms, so the
# lag t0 stays positive, as in the paper (docs/README.md, "One configuration")
means = run_preprocess(campaign, PreprocessOptions())
write_means(means, OUT / "means.nc")

table1 = read_tables(means)[0]                     # Table 1 is stored as variables (ratio)
print("Table 1 (this campaign):", {k: round(v["value"], 2) for k, v in table1.items()})

# %% 4. Identification: multi-start Levenberg-Marquardt (Algorithm 1), uncertainty
from gprm.fit import FitOptions, run_fit

# the 23 parameters of Table 3 plus the per-signal alignment offsets (docs/model.md) are the
# default; a bad option (say starts=0) raises GprmInputError naming it. The uncertainty is the
# parametric bootstrap by default (docs/fitting.md: 30 campaigns; 5 here to keep it short)
fit = run_fit(means, FitOptions(starts=12, seed=1, chunk=12, band_samples=20, boot=5),
              source="worked example")
fit.write(OUT / "fit.json")                        # + fit.nc (every start, bands)
print(fit.summary().splitlines()[2])

# %% 5. Prediction: trajectories of the contact points, kinetic energy, what-ifs (Sec. 4.2)
from gprm.predict import PredictOptions, run_predict, run_whatif
from gprm.predict.files import write_prediction, write_whatif
from gprm.fit import load_model
from gprm.run import model_notes

# what later stages read: a FittedModel (gprm.fit.load_model: 'paper', a fit JSON or a run
# folder). It reads every fit, also one without uncertainty (then fm.has_uncertainty is
# False: best fit only, said in `notes`)
fm = load_model(OUT)
notes = model_notes(fm)
print(fm.uncertainty_note, "; identified:", ", ".join(fm.identified or ()))
popts = PredictOptions(piezo=2, name="piezo2", samples=20, seed=1, means=str(OUT / "means.nc"))
# Bands come from 20 parameter sets of the fit's uncertainty method (FittedModel.sample:
# the posterior draws stored with the fit; never a set that cannot be simulated)
pred = run_predict(fm, popts)
write_prediction(pred, OUT / "predict.nc")
wi = run_whatif(fm, popts)
write_whatif(wi, OUT / "whatif.json")   # a WhatIf result (to_json/to_xarray)
for r in wi.ratios[1:]:
    print(f"overshoot Piezo 2 / {r['name']}:",
          ", ".join(f"{a} {v:.2f}" for a, v in r["headline"].items()))

# %% 6. Flight: synthetic releases, release velocities, impact times, Tukey test (Sec. 4.1)
from gprm.flight import (AnalysisOptions, ImpactOptions, SynthOptions, TelemetryOptions,
                         run_impact, run_synth_telemetry, write_impact, write_telemetry)
from gprm.flight.inference import InferenceOptions

# the entry points gprm synth telemetry, gprm impact and gprm run call; bad options raise
# GprmInputError naming them
tele = run_synth_telemetry(fm, TelemetryOptions(SynthOptions(n_releases=11, seed=1)))
write_telemetry(tele, OUT / "telemetry.nc")
# the impact-scenario posterior (docs/flight.md §11) with 2000 prior draws here for speed (the
# measured recovery uses the default, 20000); impact_model="auto": the chosen scenario's curves
imp = run_impact(fm, OUT / "telemetry.nc",
                 ImpactOptions(AnalysisOptions(n_samples=20, seed=1, impact_model="auto"),
                               scenarios=InferenceOptions(n_draws=2000, seed=1)),
                 notes=notes)
print(*notes, sep="\n")
imp = write_impact(imp, OUT / "impact.json")      # + impact.nc (the curves: imp.to_xarray())
tk = imp.tukey
print("Tukey: all compatible" if tk.get("all_compatible") else
      f"Tukey: {sum(p['reject'] for p in tk['pairs'])} pair(s) rejected")
sc = imp.scenarios
print("scenario per release:", ", ".join(r["chosen"] for r in sc["releases"]),
      "| jointly:", sc["joint"]["chosen"])

# %% 7. The report of this run directory (one self-contained HTML file)
from gprm.report.build import write_report

html = write_report(OUT, OUT / "report.html")
print(f"report: {html} ({html.stat().st_size / 1e6:.1f} MB)")
