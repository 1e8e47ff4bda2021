"""The OKane2022 fit of tests/test_fit_other_sets.py once; prints its candidates bit for bit (hex) and the test
flight error as one JSON object, to compare runs under different thread counts, loads and libm variants
(docs/notes/2026-11-27-fit-determinism.md)."""
import hashlib, json, sys, time
sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[1] / "tests"))
import numpy as np
from test_fit_other_sets import load
from gcs_pdm.fitting.procedure import FitSettings, fit_battery
t=time.perf_counter()
s = load("OKane2022")
r = fit_battery(s["train"], s["validation"], s["test"], FitSettings())
out = {"secs": round(time.perf_counter()-t,1)}
for st in r.stages:
    out[st.name] = {"chosen": st.chosen, "lm": [c.lm_rmse.hex() for c in st.candidates],
                    "sa": hashlib.sha1(np.array([c.sa_rmse for c in st.candidates]).tobytes()).hexdigest()[:10]}
out["params"] = hashlib.sha1(np.array(sorted(r.parameters.items()), dtype=object).tobytes() if False else json.dumps(sorted((k, float(v).hex()) for k,v in r.parameters.items())).encode()).hexdigest()[:12]
out["test"] = {e["flight"]: e["voltage"]["rmse"] for e in r.errors["learned"]["test"]["flights"]}
print(json.dumps(out))
