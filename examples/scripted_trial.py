"""Drive scripted recognition trials through the ActiveTouch REST API alone.

This is the pattern to copy into your own robot stack: the server plans, your robot touches.

1. Collect training touches with your robot and upload them as CSV (``POST /datasets``).
2. Fit an object manifold (``POST /models``) and wait until it is ``ready``.
3. For a trial (``POST /trials`` with ``"mode": "scripted"``), loop:
   ``GET /trials/{id}/next-action`` → perform the action → ``POST /trials/{id}/observations``
   with the action you actually performed and what you felt, until ``done``.

Here the "robot" is a stand-in: the paper's Experiment 1 world, y = h(θ, x) + noise with
h(θ, x) = [exp(-(x-θ)²), exp(-(x-θ²)²), exp(-(x-θ³)²)], objects O1..O4 at θ = -0.5, 0, 0.2, 0.5.
Replace :class:`SimulatedRobot` with your own.

Run a server (``activetouch serve``), then::

    python examples/scripted_trial.py --base-url http://127.0.0.1:8000

Only ``httpx`` and ``numpy`` are needed on the client side.
"""

from __future__ import annotations

import argparse
import io
import sys
import time
from dataclasses import dataclass, field

import httpx
import numpy as np

API = "/api/v1"


@dataclass
class SimulatedRobot:
    """A stand-in for a robot: touches object ``name`` with action x and returns y (dy = 3)."""

    thetas: dict[str, float] = field(
        default_factory=lambda: {"O1": -0.5, "O2": 0.0, "O3": 0.2, "O4": 0.5}
    )
    noise_std: float = 0.1
    rng: np.random.Generator = field(default_factory=lambda: np.random.default_rng(0))

    def touch(self, name: str, action: list[float]) -> tuple[list[float], list[float]]:
        """Perform ``action`` on object ``name``; return (action performed, observation)."""
        x = float(np.clip(action[0], -3.0, 3.0))  # a real robot clips to its own limits
        theta = self.thetas[name]
        centres = np.array([theta, theta**2, theta**3])
        y = np.exp(-((x - centres) ** 2)) + self.noise_std * self.rng.standard_normal(3)
        return [x], y.tolist()


def check(response: httpx.Response) -> dict:
    """The JSON body of a successful response; otherwise raise with the server's message."""
    if response.is_error:
        raise RuntimeError(
            f"{response.request.method} {response.request.url}: "
            f"{response.status_code} {response.text}"
        )
    return response.json()


def upload_training_data(client: httpx.Client, robot: SimulatedRobot, touches: int) -> int:
    """Touch every object ``touches`` times with x ~ N(0, 1); upload the CSV; return its id."""
    out = io.StringIO()
    out.write("object,x_1,y_1,y_2,y_3\n")
    for name in robot.thetas:
        for x in robot.rng.standard_normal(touches):
            action, y = robot.touch(name, [float(x)])
            out.write(",".join([name, *(repr(v) for v in action + y)]) + "\n")
    body = check(
        client.post(f"{API}/datasets", content=out.getvalue(), headers={"Content-Type": "text/csv"})
    )
    return int(body["id"])


def fit_model(client: httpx.Client, dataset_id: int, seed: int, timeout_s: float = 300) -> int:
    """Fit a 1-D manifold and wait for it; return the model id."""
    accepted = check(
        client.post(
            f"{API}/models",
            json={
                "dataset_id": dataset_id,
                "latent_dim": 1,
                "optimizer": "lbfgs",
                "restarts": 1,
                "seed": seed,
            },
        )
    )
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        model = check(client.get(f"{API}/models/{accepted['id']}"))
        if model["status"] == "ready":
            return int(model["id"])
        if model["status"] == "failed":
            raise RuntimeError(f"fit failed: {model['reason']}")
        time.sleep(0.2)
    raise TimeoutError(f"model {accepted['id']} not ready after {timeout_s} s")


def run_trial(
    client: httpx.Client,
    robot: SimulatedRobot,
    model_id: int,
    target: str,
    seed: int,
    max_steps: int = 20,
    confidence: float = 0.99,
) -> dict:
    """One scripted trial on object ``target``; return the finished trial."""
    trial = check(
        client.post(
            f"{API}/trials",
            json={
                "model_id": model_id,
                "mode": "scripted",
                "policy": "active",
                "max_steps": max_steps,
                "target": target,
                "seed": seed,
            },
        )
    )
    done = False
    while not done:
        advice = check(client.get(f"{API}/trials/{trial['id']}/next-action"))
        performed, observation = robot.touch(target, advice["action"])
        update = check(
            client.post(
                f"{API}/trials/{trial['id']}/observations",
                json={"action": performed, "observation": observation},
            )
        )
        done = update["done"]
    return check(client.get(f"{API}/trials/{trial['id']}"))


def run(
    client: httpx.Client,
    trials_per_object: int = 1,
    touches: int = 25,
    seed: int = 0,
    model_id: int | None = None,
) -> list[dict]:
    """Upload data, fit (unless ``model_id``), run trials on every object; return the trials."""
    robot = SimulatedRobot(rng=np.random.default_rng(seed))
    if model_id is None:
        model_id = fit_model(client, upload_training_data(client, robot, touches), seed)
    results = []
    for repeat in range(trials_per_object):
        for index, name in enumerate(robot.thetas):
            trial = run_trial(client, robot, model_id, name, seed=seed + 100 * repeat + index)
            results.append(trial)
            answer = trial["result"]["object"]
            print(
                f"trial {trial['id']}: touched {name}, answer {answer} after "
                f"{trial['n_steps']} touches ({'right' if answer == name else 'WRONG'})"
            )
    return results


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base-url", default="http://127.0.0.1:8000")
    parser.add_argument("--token", help="API token, if the server requires one")
    parser.add_argument("--model-id", type=int, help="use this ready model instead of fitting")
    parser.add_argument("--trials-per-object", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    headers = {"Authorization": f"Bearer {args.token}"} if args.token else {}
    with httpx.Client(base_url=args.base_url, headers=headers, timeout=30) as client:
        trials = run(client, args.trials_per_object, seed=args.seed, model_id=args.model_id)
    right = sum(t["result"]["correct"] for t in trials)
    print(f"{right}/{len(trials)} objects named correctly")
    return 0 if right == len(trials) else 1


if __name__ == "__main__":
    sys.exit(main())
