"""Training the appearance cue's network (``mocap-tracker train-appearance``, and a missing default
network when a command asks for it): render the training recordings (held-out takes excluded) and
gesture scripts on random synthetic people (some in randomised scenes), then train each network of
the ensemble on its passes.

Needs PyTorch (imported inside :func:`train_appearance`); the tracker itself does not.
"""

from __future__ import annotations

import os
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

from tracker_service.app.gesture_files import gesture_scripts
from tracker_service.app.options import Passes, TrainAppearanceOptions

__all__ = ["train_appearance"]


def _pass_plan(options: TrainAppearanceOptions) -> tuple[int, Passes]:
    """The number of networks and each one's passes (``--members``, ``--passes``)."""
    from tracker_service.build.appearance_train import MEMBER_PASSES

    passes = options.passes
    n = options.members or (len(passes) if passes else len(MEMBER_PASSES))
    plan = passes or MEMBER_PASSES[:n]
    if len(plan) != n:
        raise ValueError(f"{n} network(s) need {n} pass list(s) separated by ';' in --passes, got {len(plan)}"
                         if passes else f"--members {n}: the defaults cover {len(MEMBER_PASSES)} networks; "
                         f"give each one's --passes (';'-separated)")
    return n, plan


def _configs(options: TrainAppearanceOptions, n: int, plan: Passes) -> list[Any]:
    """One :class:`~tracker_service.build.appearance_train.TrainConfig` per network."""
    from tracker_service.build.appearance_train import (
        MEMBER_POSTURE_PASSES,
        MEMBER_VARY_PASSES,
        TrainConfig,
        member_extra_passes,
    )

    extra: dict[str, Passes] = {}
    for field_name, table, flag, what in (("posture_passes", MEMBER_POSTURE_PASSES, "--posture-passes", "posture"),
                                          ("vary_passes", MEMBER_VARY_PASSES, "--vary-passes", "randomised")):
        given = getattr(options, field_name)
        lists = member_extra_passes(table, n) if given is None else given
        if lists and len(lists) != n:
            raise ValueError(f"{n} network(s) need {n} {what} pass list(s) separated by ';' in {flag}, "
                             f"got {len(lists)}")
        extra[field_name] = lists or ((),) * n  # none: an empty list for every network
    base = TrainConfig()
    if options.epochs is not None:
        base = replace(base, epochs=options.epochs)
    if options.width is not None:
        base = replace(base, width=options.width)
    if options.masks is not None:
        base = replace(base, masks=options.masks)
    return [replace(base, passes=plan[k], posture_passes=extra["posture_passes"][k],
                    vary_passes=extra["vary_passes"][k], seed=k) for k in range(n)]


def _render_views(entries: list[Any], configs: list[Any], data: Path, jobs: int) -> None:
    """Render (or find cached) every pass's training views under ``data``."""
    from tqdm import tqdm

    from tracker_service.build.appearance_train import render_samples

    every_pass = tuple(dict.fromkeys(p for c in configs for p in c.passes))
    with tqdm(desc="render training views", unit="take") as bar:
        def rendered(done: int, total: int) -> None:
            bar.total = total
            bar.n = done
            bar.refresh()

        sub = configs[0].masks == "subtracted"
        render_samples(entries, every_pass, configs[0].size, data, jobs, rendered, load=False, subtracted=sub)
        every_posture = tuple(dict.fromkeys(p for c in configs for p in c.posture_passes))
        if every_posture:
            render_samples(entries, every_posture, configs[0].size, data, jobs, rendered, load=False,
                           posture=configs[0].posture, subtracted=sub)
        every_varied = tuple(dict.fromkeys(p for c in configs for p in c.vary_passes))
        if every_varied:
            render_samples(entries, every_varied, configs[0].size, data, jobs, rendered, load=False, vary=True,
                           subtracted=sub)


def _train_networks(entries: list[Any], configs: list[Any], data: Path, jobs: int) -> list[Any]:
    """Train one network per config on its cached views."""
    from tqdm import tqdm

    from tracker_service.build.appearance_train import config_samples, train_network

    nets = []
    for k, cfg in enumerate(configs):
        samples = config_samples(entries, cfg, data)  # cached: read only
        with tqdm(total=cfg.epochs, desc=f"train network {k + 1}/{len(configs)} on {len(samples)} views",
                  unit="epoch") as bar:
            def trained(epoch: int, epochs: int, fig: dict[str, float]) -> None:
                bar.update(1)
                bar.set_postfix({name: round(v, 4) for name, v in fig.items() if name != "seconds"})

            nets.append(train_network(samples, cfg, threads=max(jobs, 1), progress=trained))
        del samples
    return nets


def train_appearance(out: Path, options: TrainAppearanceOptions) -> dict[str, Any]:
    """Render the training views and train the ensemble into ``out``; returns the network's
    metadata (its members' figures, ``render_s``, ``train_s``, ``mocap``, ``training_takes``,
    ``scripts``). ``options.out`` is not read: ``out`` is the resolved file."""
    from tracker_service.build.appearance_train import training_takes
    from tracker_service.build.database import is_held_out
    from tracker_service.cues.appearance import ensemble, save_appearance

    n, plan = _pass_plan(options)
    if options.mocap:
        os.environ["MOCAP_DATA"] = options.mocap
    from protocol.formats.mocap_data import index_entries, mocap_root

    root = mocap_root()
    recordings = [(i, str(root / e.path)) for i, e in enumerate(index_entries()) if not is_held_out(i)]
    if options.takes:
        recordings = recordings[:options.takes]
    script_files = gesture_scripts(options.scripts)
    entries = training_takes(recordings, script_files)
    configs = _configs(options, n, plan)
    t0 = time.perf_counter()
    _render_views(entries, configs, out.parent / "data", options.jobs)
    t1 = time.perf_counter()
    nets = _train_networks(entries, configs, out.parent / "data", options.jobs)
    net = nets[0] if n == 1 else ensemble(nets)
    common = {"render_s": round(t1 - t0, 1), "train_s": round(time.perf_counter() - t1, 1), "mocap": str(root),
              "training_takes": len(recordings), "scripts": [str(p) for p in script_files]}
    meta = net.meta | common
    save_appearance(out, replace(net, meta=meta))
    return dict(meta)
