"""Throughput of an env (``SimShearTracking-v0``, or ``--env`` another) with translated ("real") 128 px images: one
process and vectorised.

``simshear evaluate env-speed`` steps the env with its oracle controller (driven from ``info``, so the env runs
in ``obs_mode="real"``, translating every image; ``SimShearEdgeFollow-v0``: the edge law on the true offset, depth
and angle; ``SimShearPush-v0``: the push law on the true depth, shear and face yaw) and writes
``results/env_speed.json`` (several ``--env``: one section each under ``envs``, e.g. ``results/env_speed_tasks.json``
of the edge following and pushing envs):

- single process: ``gymnasium.make`` and a loop, per translator runtime of ``--runtimes``: torch on each of the
  ``--threads`` settings, ONNX Runtime (:mod:`simshear_gym.models.translator_runtime`) on each of the
  ``--onnx-threads`` settings (intra-op threads; default one);
  the same loop in ``"sim"`` mode and the translator alone at batch 1 show where the time goes (each row's
  ``translator_share_of_step``: the translator's batch-1 time over the step's; ``translation_ms_in_step``: the
  step's time over the sim-mode step's);
- vectorised: ``gymnasium.make_vec(num_envs=--num-envs)`` with ``--workers`` worker processes, per runtime of
  ``--vector-runtimes`` (default the envs' own, ``auto``), translating in the workers (one thread each) and, for
  comparison, in the main process (torch on ``--threads`` threads, ONNX Runtime on one).

``--sensor RUN`` (a ``simshear pipeline run`` folder, its ``sensor.json`` or ``configs/<name>.toml``) measures the
single-process runs again with that sensor's models (``gym.make(..., sensor=RUN)``: its TacTip, its translator and,
where the run exported it, the ``.onnx`` beside it): rows with ``"models": "sensor"`` beside the shipped models'
(``"models": "shipped"``), a ``sensor`` entry in the record naming the run and its translator, and under ``goals``
the shipped models' rate over the sensor's (issue 44: at most :data:`GOAL_SENSOR_SLOWDOWN`). The vectorised runs use
the shipped models.

The runtime is chosen for the env (and its workers) by ``$SIMSHEAR_TRANSLATOR_RUNTIME``
(:func:`simshear_gym.models.translator_runtime.choose_translator_runtime`). Goals: >= 100 steps/s in one process
(>= 300 for the edge following and pushing envs, issue 43), >= 600 steps/s vectorised over both cores, and (issue
22) translated steps in one process at least half as many per second as raw sim steps. The machine's load average
before each run is recorded: on a shared machine other jobs take
cores and the numbers with them; the single-process rows also give the process's CPU time per step (all its
threads), which other jobs disturb less.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import time
from pathlib import Path

import numpy as np

from simshear_gym.evaluate.records import write_record
from simshear_gym.machine import machine_info

GOAL_SINGLE_STEPS_PER_S = 100.0
GOAL_TASK_SINGLE_STEPS_PER_S = 300.0  # issue 43: the edge following and pushing envs, one process
GOAL_VECTOR_STEPS_PER_S = 600.0  # issue 22 (the earlier goal was 200)
GOAL_TRANSLATED_SHARE_OF_SIM_RATE = 0.5
GOAL_SENSOR_SLOWDOWN = 1.2  # issue 44: a sensor's own models step at least 1 / 1.2 of the shipped models' rate


def _load() -> float:
    return round(os.getloadavg()[0], 2)


ENV_CONTACTS = {"SimShearTracking-v0": "surface", "SimShearEdgeFollow-v0": "edge", "SimShearPush-v0": "surface"}
"""The envs measured (``--env``) and the contact type of their translator."""


def oracle_from_info(env_id: str, env):
    """(controller, info -> its observation) of an env's oracle, driven from ``info`` in any observation mode (one
    env's info, or a vector env's batched info row by row through ``numpy`` indexing)."""
    if env_id == "SimShearEdgeFollow-v0":
        from simshear_gym.control.edge_servo import EdgeOracleController

        def edge_state(info: dict) -> dict:
            return {"true_pose_shear": np.stack([np.asarray(info[k], dtype=np.float64) for k in (
                "edge_offset_mm", "depth_mm", "shear_along_edge_mm", "edge_angle_deg")], axis=-1)}

        return EdgeOracleController.for_env(env), edge_state
    if env_id == "SimShearPush-v0":
        from simshear_gym.control.push_servo import PushOracleController

        def push_state(info: dict) -> dict:
            shear = np.asarray(info["shear_sensor_mm_deg"], dtype=np.float64)
            variables = [np.asarray(info["depth_mm"], dtype=np.float64), shear[..., 0],
                         np.asarray(info["rz_error_deg"], dtype=np.float64),
                         np.zeros_like(np.asarray(info["depth_mm"], dtype=np.float64))]
            return {"true_pose_shear": np.stack(variables, axis=-1), "goal": np.asarray(info["goal"])}

        return PushOracleController.for_env(env), push_state
    from simshear_gym.control.oracle import OracleController, true_pose_shear_from_info

    return OracleController.for_env(env), lambda info: {"true_pose_shear": true_pose_shear_from_info(info)}


def single_process(obs_mode: str, steps: int, warmup: int = 20, env_id: str = "SimShearTracking-v0",
                   sensor: str | None = None) -> dict:
    """Steps per second of one env driven by the oracle from ``info`` (episodes reset as they end), with the shipped
    models or a ``sensor``'s (:func:`~simshear_gym.models.zoo.load_sensor`)."""
    import gymnasium as gym

    import simshear_gym.envs  # noqa: F401

    load = _load()
    env = gym.make(env_id, obs_mode=obs_mode, **({"sensor": sensor} if sensor is not None else {}))
    controller, state_of = oracle_from_info(env_id, env)
    _, info = env.reset(seed=0)
    done_steps, start = 0, None
    for index in range(steps + warmup):
        if index == warmup:
            start, cpu_start = time.perf_counter(), time.process_time()
        action = controller(state_of(info))
        _, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            _, info = env.reset()
            controller.reset()
        done_steps += index >= warmup
    seconds, cpu_seconds = time.perf_counter() - start, time.process_time() - cpu_start
    env.close()
    return {"obs_mode": obs_mode, "steps": done_steps, "seconds": round(seconds, 3),
            "steps_per_s": round(done_steps / seconds, 1), "ms_per_step": round(1000 * seconds / done_steps, 3),
            "cpu_ms_per_step": round(1000 * cpu_seconds / done_steps, 3), "load_average_before": load}


def vectorised(num_envs: int, workers: int, translate_in: str, steps: int, warmup: int = 5,
               env_id: str = "SimShearTracking-v0") -> dict:
    """Steps per second (summed over sub-envs) of ``make_vec`` in "real" mode."""
    import gymnasium as gym

    import simshear_gym.envs  # noqa: F401

    load = _load()
    probe = gym.make(env_id, obs_mode="sim")  # the oracles' settings (reference depth, scale, speed)
    pairs = [oracle_from_info(env_id, probe) for _ in range(num_envs)]
    probe.close()
    controllers, state_of = [pair[0] for pair in pairs], pairs[0][1]
    envs = gym.make_vec(env_id, num_envs=num_envs, obs_mode="real", workers=workers, translate_in=translate_in)
    _, info = envs.reset(seed=0)
    start = None
    for index in range(steps + warmup):
        if index == warmup:
            start = time.perf_counter()
        state = state_of(info)
        actions = np.stack([controller({key: value[index] for key, value in state.items()})
                            for index, controller in enumerate(controllers)])
        _, _, terminated, truncated, info = envs.step(actions)
        for env_index in np.flatnonzero(terminated | truncated):
            controllers[env_index].reset()
    seconds = time.perf_counter() - start
    envs.close()
    total = steps * num_envs
    return {"num_envs": num_envs, "workers": workers, "translate_in": translate_in, "vector_steps": steps,
            "env_steps": total, "seconds": round(seconds, 3), "steps_per_s": round(total / seconds, 1),
            "load_average_before": load}


@contextlib.contextmanager
def _environment(name: str, value: str):
    """``$name`` set to ``value`` inside (the envs built and the vector env workers started there read it)."""
    previous = os.environ.get(name)
    os.environ[name] = value
    try:
        yield
    finally:
        if previous is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = previous


@contextlib.contextmanager
def translator_runtime(runtime: str, translator: str = "full", threads: int = 1):
    """The envs built (and the vector env workers started) inside run the shipped ``translator`` ("full" or
    "student") on ``runtime`` (ONNX Runtime on ``threads`` intra-op threads)."""
    from simshear_gym.models.translator_runtime import TRANSLATOR_ENV, TRANSLATOR_RUNTIME_ENV, TRANSLATOR_THREADS_ENV

    with (_environment(TRANSLATOR_RUNTIME_ENV, runtime), _environment(TRANSLATOR_ENV, translator),
          _environment(TRANSLATOR_THREADS_ENV, str(threads))):
        yield


def surface_translator(runtime: str, translator: str = "full", threads: int = 1, contact: str = "surface"):
    """The shipped translator of a contact type (surface by default; "full", or its "student") on ``runtime`` (ONNX
    Runtime on ``threads`` threads), as the envs load it."""
    from simshear_gym.models.translator_runtime import translator_from
    from simshear_gym.models.zoo import shipped_translator, translator_weights

    if translator == "student":
        return translator_from(translator_weights(contact, student=True), runtime, threads=threads)
    return shipped_translator(contact, runtime=runtime, threads=threads)


def sensor_translator(sensor: str, runtime: str, threads: int = 1, contact: str = "surface"):
    """A sensor's own translator of a contact type (:func:`~simshear_gym.models.zoo.load_sensor`) on ``runtime``
    (ONNX Runtime on ``threads`` threads), as the envs made with ``sensor=`` load it."""
    from simshear_gym.models.translator_runtime import translator_from
    from simshear_gym.models.zoo import load_sensor

    return translator_from(load_sensor(sensor).translator(contact), runtime, threads=threads)


def translator_batch1_ms(runtime: str = "torch", repeats: int = 200, translator: str = "full",
                         threads: int = 1, contact: str = "surface", sensor: str | None = None) -> float:
    """Median batch-1 latency (ms) of a shipped translator (surface by default, or its student), or of a
    ``sensor``'s own, on ``runtime`` (ONNX Runtime on ``threads`` threads)."""
    from simshear_gym.evaluate.translator_speed import latency_ms

    model = (sensor_translator(sensor, runtime, threads, contact) if sensor is not None
             else surface_translator(runtime, translator, threads, contact))
    return round(latency_ms(model, 1, repeats, np.random.default_rng(0)), 3)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--env", nargs="+", default=["SimShearTracking-v0"], choices=tuple(ENV_CONTACTS),
                        help="the envs measured, one after the other (default SimShearTracking-v0); with several, "
                             "the record holds one section per env under 'envs'")
    parser.add_argument("--steps", type=int, default=500, help="measured steps of the single-process runs")
    parser.add_argument("--vector-steps", type=int, default=40, help="measured steps of each vectorised run")
    parser.add_argument("--num-envs", type=int, nargs="+", default=[8, 16, 32], help="sub-envs of the vectorised runs")
    parser.add_argument("--workers", type=int, default=2, help="worker processes of the vectorised runs")
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2],
                        help="torch threads of the main process: each setting is measured (torch runtime)")
    parser.add_argument("--runtimes", nargs="+", choices=("torch", "onnx"), default=["torch", "onnx"],
                        help="translator runtimes of the single-process runs (onnx: ONNX Runtime on each "
                             "--onnx-threads setting, needs onnxruntime and the shipped .onnx; default both)")
    parser.add_argument("--onnx-threads", type=int, nargs="+", default=[1],
                        help="ONNX Runtime intra-op threads of the single-process runs: each setting is measured "
                             "(default 1; the vectorised runs' workers use one each)")
    parser.add_argument("--vector-runtimes", nargs="+", choices=("auto", "torch", "onnx"), default=["auto"],
                        help="translator runtimes of the vectorised runs (default auto: the envs' default, ONNX "
                             "Runtime where it can)")
    parser.add_argument("--translators", nargs="+", choices=("full", "student"), default=["full"],
                        help="shipped translators measured: full (the shPix2pix) and/or student (its distilled "
                             "student, from the zoo's student folder; the envs' translator='student')")
    parser.add_argument("--sensor", default=None, metavar="RUN",
                        help="a sensor's own models (a simshear pipeline run folder, its sensor.json or "
                             "configs/<name>.toml): the single-process runs are measured with them too, beside the "
                             "shipped models', and the record names the sensor (default: shipped models only)")
    parser.add_argument("--out", type=Path, default=Path("results"), help="results directory")
    parser.add_argument("--name", default="env_speed", help="base name of the json written")


def run(args: argparse.Namespace) -> int:
    for name in ("steps", "vector_steps", "workers"):
        if getattr(args, name) < 1:
            raise ValueError(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    for name in ("num_envs", "threads", "onnx_threads"):
        if min(getattr(args, name)) < 1:
            raise ValueError(f"--{name.replace('_', '-')} values must be >= 1, got {getattr(args, name)}")
    env_ids = list(dict.fromkeys(args.env))
    sensor = args.sensor
    head = {"machine": machine_info()}
    if sensor is not None:
        head["sensor"] = sensor_record(sensor, env_ids)  # before measuring: a sensor without a contact type fails here
    sections = {env_id: measure(args, env_id) for env_id in env_ids}
    payload = {**head, **sections[env_ids[0]]} if len(env_ids) == 1 else {**head, "envs": sections}
    write_record("simshear evaluate env-speed", add_arguments, args, args.out / f"{args.name}.json", payload)
    print(f"wrote {args.out / f'{args.name}.json'}")
    return 0


def sensor_record(sensor: str, env_ids: list[str]) -> dict:
    """What the record says of ``--sensor``: the argument, the sensor's name and per env its translator and the
    runtime the envs' ``"auto"`` picks for it (``onnx`` where the run exported it and onnxruntime is installed)."""
    from simshear_gym.models.translator_runtime import runtime_of
    from simshear_gym.models.zoo import load_sensor

    models = load_sensor(sensor)
    translators = {env_id: models.translator(ENV_CONTACTS[env_id]) for env_id in env_ids}
    return {"run": str(sensor), "name": models.name, "translators": translators,
            "auto_runtime": {env_id: runtime_of(sensor_translator(sensor, "auto", contact=ENV_CONTACTS[env_id]))
                             for env_id in env_ids}}


def measure(args: argparse.Namespace, env_id: str) -> dict:
    """One env's section of the record: single-process and vectorised rows, and the goals."""
    import torch

    from simshear_gym.models.translator_runtime import runtime_of

    print(f"{env_id}:")
    runtimes = list(dict.fromkeys(args.runtimes))
    translators = list(dict.fromkeys(args.translators))
    contact = ENV_CONTACTS[env_id]
    sensor = args.sensor
    single = {"sim": single_process("sim", args.steps, env_id=env_id), "real": []}
    sim_row = single["sim"]
    print(f"one process, sim 128 px: {sim_row['steps_per_s']:.0f} steps/s ({sim_row['ms_per_step']:.2f} ms/step)")
    if sensor is not None:
        single["sensor_sim"] = single_process("sim", args.steps, env_id=env_id, sensor=sensor)
        print(f"one process, sim 128 px, sensor's TacTip: {single['sensor_sim']['steps_per_s']:.0f} steps/s")
    # (models, translator, runtime, torch threads of the main process, ONNX Runtime's intra-op threads); a sensor's
    # rows right after the shipped ones of the same setting, so that both see the same load
    settings = [(models, translator, runtime, threads, 1) if runtime == "torch"
                else (models, translator, runtime, 1, threads)
                for translator in translators for runtime in runtimes
                for threads in (args.threads if runtime == "torch" else args.onnx_threads)
                for models in ("shipped", *(("sensor",) if sensor is not None and translator == "full" else ()))]
    for models, translator, runtime, threads, onnx_threads in settings:
        torch.set_num_threads(threads)
        from_sensor = sensor if models == "sensor" else None
        with translator_runtime(runtime, translator, onnx_threads):
            row = {"models": models, "translator": "sensor" if from_sensor else translator, "torch_threads": threads,
                   "translator_runtime": runtime, **({"onnx_threads": onnx_threads} if runtime == "onnx" else {}),
                   **single_process("real", args.steps, env_id=env_id, sensor=from_sensor),
                   "translator_ms_batch1": translator_batch1_ms(runtime, translator=translator,
                                                                threads=onnx_threads, contact=contact,
                                                                sensor=from_sensor)}
        sim_base = single["sensor_sim"] if from_sensor else sim_row  # the same TacTip untranslated
        row["translator_share_of_step"] = round(row["translator_ms_batch1"] / row["ms_per_step"], 3)
        row["translation_ms_in_step"] = round(row["ms_per_step"] - sim_base["ms_per_step"], 3)
        row["steps_per_s_over_sim"] = round(row["steps_per_s"] / sim_base["steps_per_s"], 3)
        single["real"].append(row)
        print(f"one process, real 128 px, {row['translator']} translator, {runtime}"
              f"{f' (torch threads {threads})' if runtime == 'torch' else f' ({onnx_threads} threads)'}: "
              f"{row['steps_per_s']:.0f} steps/s ({row['ms_per_step']:.2f} ms/step, {row['cpu_ms_per_step']:.2f} "
              f"CPU ms/step, {row['steps_per_s_over_sim']:.2f} x sim's rate); translator at batch 1 "
              f"{row['translator_ms_batch1']:.2f} ms = {100 * row['translator_share_of_step']:.0f} % of a step")
    vector = []
    vector_runtimes = {runtime: runtime_of(surface_translator(runtime))  # auto -> its choice
                       for runtime in dict.fromkeys(args.vector_runtimes)}
    for translator in translators:
        for num_envs in args.num_envs:
            for requested, runtime in vector_runtimes.items():
                vector += _vector_rows(args, translator, num_envs, requested, runtime, env_id)
    shipped_rows = [row for row in single["real"] if row["models"] == "shipped"]
    best_single = max(row["steps_per_s"] for row in shipped_rows)
    best_vector = max(row["steps_per_s"] for row in vector)
    best_by_runtime = {f"{translator}/{runtime}": max(
        row["steps_per_s"] for row in shipped_rows
        if (row["translator"], row["translator_runtime"]) == (translator, runtime))
        for translator in translators for runtime in runtimes}
    sensor_goals = sensor_goal(single["real"], runtimes) if sensor is not None and "full" in translators else {}
    goal_single = GOAL_SINGLE_STEPS_PER_S if env_id == "SimShearTracking-v0" else GOAL_TASK_SINGLE_STEPS_PER_S
    return {
        "env": (f"{env_id}, obs_mode='real' (the shipped shPix2pix {contact} translator, 'full', or its "
                "distilled 'student'; runtime per row: torch, or ONNX Runtime on the .onnx beside the weights), "
                "128 px, oracle actions"),
        "single_process": single, "vectorised": vector,
        "goals": {"single_steps_per_s": goal_single, "vector_steps_per_s": GOAL_VECTOR_STEPS_PER_S,
                  "best_single_steps_per_s": best_single, "best_vector_steps_per_s": best_vector,
                  "single_met": best_single >= goal_single,
                  "vector_met": best_vector >= GOAL_VECTOR_STEPS_PER_S,
                  "translated_over_sim_rate": GOAL_TRANSLATED_SHARE_OF_SIM_RATE,
                  "best_single_steps_per_s_by_runtime": best_by_runtime,
                  "translated_over_sim_rate_by_runtime": {
                      runtime: round(rate / sim_row["steps_per_s"], 3) for runtime, rate in best_by_runtime.items()},
                  "translated_over_sim_met": max(best_by_runtime.values()) >= (
                      GOAL_TRANSLATED_SHARE_OF_SIM_RATE * sim_row["steps_per_s"]),
                  **({"sensor": sensor_goals} if sensor_goals else {})},
    }


def sensor_goal(rows: list[dict], runtimes: list[str]) -> dict:
    """The shipped (full) translator's best single-process rate over the sensor's, per runtime and best against
    best, against :data:`GOAL_SENSOR_SLOWDOWN`."""
    def best(models: str, runtime: str | None = None) -> float:
        return max(row["steps_per_s"] for row in rows if row["models"] == models
                   and row["translator"] in ("full", "sensor") and runtime in (None, row["translator_runtime"]))

    by_runtime = {runtime: round(best("shipped", runtime) / best("sensor", runtime), 3) for runtime in runtimes}
    slowdown = round(best("shipped") / best("sensor"), 3)
    return {"shipped_over_sensor_rate": slowdown, "shipped_over_sensor_rate_by_runtime": by_runtime,
            "best_sensor_steps_per_s": best("sensor"), "goal_shipped_over_sensor_rate": GOAL_SENSOR_SLOWDOWN,
            "met": slowdown <= GOAL_SENSOR_SLOWDOWN}


def _vector_rows(args: argparse.Namespace, translator: str, num_envs: int, requested: str, runtime: str,
                 env_id: str) -> list:
    """The vectorised rows of one translator, sub-env count and runtime: translating in the workers, and in the
    main process on each thread setting."""
    import torch

    rows = []
    main_threads = args.threads if runtime == "torch" else [1]
    for translate_in, threads in [("workers", 1)] + [("main", threads) for threads in main_threads]:
        torch.set_num_threads(threads)  # the main process's (workers use one thread each)
        with translator_runtime(requested, translator):
            row = {"translator": translator, "torch_threads_main": threads, "translator_runtime": runtime,
                   **vectorised(num_envs, args.workers, translate_in, args.vector_steps, env_id=env_id)}
        rows.append(row)
        print(f"make_vec {num_envs} envs, {args.workers} workers, {translator} translator, {runtime}, translating in "
              f"{translate_in}"
              f"{f' ({threads} threads)' if translate_in == 'main' and runtime == 'torch' else ''}: "
              f"{row['steps_per_s']:.0f} steps/s")
    return rows
