import sys, json, numpy as np
from btel.datasets import synthetic_route
from btel.methods import make_method
from btel.evaluation.measure import evaluate
route = synthetic_route(2000, 512, seed=0)
out = {}
for name in ["btel-c", "btel-r", "pq", "bruteforce"]:
    params = {} if name == "bruteforce" else {"budget": "64KB"}
    if name.startswith("btel"): params["random_state"] = 0; params["n_jobs"] = 1
    r = evaluate(make_method(name, **params), route.map, route.queries, name=name)
    out[name] = {"bytes": r.nbytes, "recall": r.recall, "R@K": r.recall_at_k}
print(json.dumps(out))
