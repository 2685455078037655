"""GA evaluation keeps metrics, not traces: its memory does not grow with the number of steps.
Measured in a fresh process (its peak RSS, ``VmHWM``)."""

import json
import subprocess
import sys
import textwrap

SCRIPT = textwrap.dedent(
    """
    import json, math
    import numpy as np
    import engine
    from engine import CartesianTask, paper_task, table1_robot, tune

    def peak_mib():
        # VmHWM is this process's own peak; ru_maxrss would include the parent's RSS at the fork
        with open("/proc/self/status") as status:
            return next(int(line.split()[1]) for line in status if line.startswith("VmHWM")) / 1024

    engine.warm_up()
    robot = table1_robot()
    paper = paper_task(robot)
    task = CartesianTask.from_q0(robot, paper.q0, paper.target_position, paper.target_attitude,
                                 duration=50.0, ramp_time=5.0, dt=0.025, joint_speed_limit=math.radians(6.0))
    task.samples
    before = peak_mib()
    result = tune(robot, task, "adaptive", population=1000, generations=1, seed=0)
    print(json.dumps({"before": before, "after": peak_mib(), "evaluations": result.evaluations, "steps": task.n_steps}))
    """
)


def test_ga_evaluation_memory_is_independent_of_the_path_length():
    """Population 1000 on a 2,000-step task (about 2,000 plans, 4 million plan-samples): the
    former numpy evaluation kept about 0.79 KB per plan-sample (several GB here); the kernel
    keeps a metrics row per individual."""
    # Compiling the kernels (a cold cache) takes a few hundred MB once; measure a process that
    # loads them from the cache, as the API and the workers do after start-up.
    subprocess.run([sys.executable, "-c", "import engine; engine.warm_up()"], check=True, timeout=600)
    out = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, timeout=600, check=True)
    numbers = json.loads(out.stdout.strip().splitlines()[-1])
    assert numbers["steps"] == 2000 and numbers["evaluations"] > 1500
    assert numbers["after"] - numbers["before"] < 16.0, numbers
    assert numbers["after"] < 300.0, numbers
