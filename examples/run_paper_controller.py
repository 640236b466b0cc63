"""Run the paper's safe controller on a built-in scenario and print what happened.

    python examples/run_paper_controller.py [SCENARIO] [HORIZON_SECONDS]
"""

import sys

from pan1_env import experiment, scenario

name = sys.argv[1] if len(sys.argv) > 1 else "paper_pa_mixed_square"
horizon = float(sys.argv[2]) if len(sys.argv) > 2 else 20.0

sc = scenario.load(name)
for controller in ("nominal", "safe"):
    m = experiment.run(sc, controller, horizon=horizon).metrics
    hit = [a["index"] + 1 for a in m["arms"] if a["collided"]]
    print(f"{name} / {controller}: collided arms (1-based) {hit or 'none'}, "
          f"min clearance {1000 * m['min_clearance_m']:+.1f} mm, "
          f"max edge error after {horizon:g} s: {m['final_max_edge_error_m']:.3g} m")
