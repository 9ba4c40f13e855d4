"""BRF-GS training: set-up, stage 1, stage 2 (or one joint / CIR phase), checkpoints, resume.

The :class:`Trainer` only orchestrates; the parts are
- :mod:`brfgs.train.run_folder` — the run folder, run.json, the log;
- :mod:`brfgs.train.state` — the tensors of a run and its checkpoints / model file;
- :mod:`brfgs.train.setup` — bands, initialisation, autoencoder, initial Gaussians, heads;
- :mod:`brfgs.train.step` — forward pass and losses of one step;
- :mod:`brfgs.train.schedule` — learning rates; :mod:`brfgs.train.strategy` — densification;
- :mod:`brfgs.train.phases` — the phases (paper section 3.3).

Rerunning on an unfinished run folder resumes from checkpoints/last.safetensors and reproduces
the uninterrupted run bit for bit; a finished folder is refused without ``overwrite``.

Data-parallel training (:mod:`brfgs.train.distributed`): with a ``comm`` of N ranks each step's
``views_per_step`` views are shared out, gradients and densification statistics summed; rank 0
prepares the folder, runs the set-up and writes every file, the other ranks start from its
first checkpoint (the resume path) and stay identical to it.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
import time
from pathlib import Path
from typing import Callable

import torch
from tqdm import tqdm

from brfgs.data import read_scene
from brfgs.data.lock import folder_lock
from brfgs.data.paths import check_outside
from brfgs.errors import UserError
from brfgs.model import DensifyState, NamedAdam
from brfgs.render import configure_threads
from brfgs.train.config import TrainConfig, scaled_schedule, with_gaussian_cap
from brfgs.train.distributed import Comm, check_identical, check_views_per_step, launch, reduce_gradients, shard
from brfgs.train.images import TrainImages
from brfgs.train.phases import Phase, next_phase, run_plan
from brfgs.train.run_folder import RunFolder
from brfgs.train.schedule import learning_rates
from brfgs.train.from_stage1 import start_from_stage1
from brfgs.train.setup import fit_autoencoder, init_head, run_setup
from brfgs.train.dense_depth import load_dense_depth
from brfgs.train.state import TrainState
from brfgs.train.step import forward, make_batch, neighbours, pick_view
from brfgs.train.strategy import ADCStrategy, MCMCStrategy, make_strategy


class Trainer:
    """One training run of ``cfg`` on ``scene_path`` into ``out_dir`` (see the module docstring).

    ``callback(phase_name, step)`` is called after every step; ``from_stage1`` starts stage 2
    from another run's checkpoints/stage1.safetensors; ``log`` prints progress lines; ``comm``:
    the ranks of a data-parallel run (:mod:`brfgs.train.distributed`; default one process).
    """

    def __init__(self, scene_path, out_dir, cfg: TrainConfig, overwrite: bool = False, progress: bool = True,
                 callback: Callable[[str, int], None] | None = None, from_stage1: str | Path | None = None,
                 log: Callable[..., None] | None = print, comm: Comm | None = None):
        self.scene_path = Path(scene_path)
        self.folder = RunFolder(out_dir)
        self.out = self.folder.out
        self.cfg = self.folder.started_cap(cfg.validate())
        self.comm = comm or Comm()
        check_views_per_step(self.cfg.views_per_step, self.comm.world)
        self.overwrite = overwrite
        self.progress = progress and self.comm.is_main
        self.callback = callback
        self.from_stage1 = Path(from_stage1) if from_stage1 else None
        self.log = (log if self.comm.is_main else None) or (lambda *a, **k: None)
        self.state = TrainState(self.cfg)
        self.phases = run_plan(self.cfg)
        self.scene = None
        self.images: TrainImages | None = None
        self.history: list[tuple[str, int, float, float]] = []  # (phase, step, loss, psnr) of this process
        self._ctrl_c = False  # Ctrl-C seen by this process (see _steps_finish_on_ctrl_c)
        self._aborted = False  # a second Ctrl-C stopped a step half done: its state is not saved
        self._stop_requested = False  # ... by any rank, agreed at the end of the last step
        self.comm_totals: dict[str, list[int]] = {}  # phase -> [all-reduced bytes, steps] of this process
        self.schedule: dict | None = None  # the schedule scaled to the training views (set when the scene is read)

    # -------------------------------------------------------------------------------- entry
    def run(self) -> Path:
        """Train (or resume) to the end; returns the path of model.safetensors."""
        self._set_threads()
        check_outside(self.out, self.scene_path)
        self._on_main(lambda: self.folder.prepare(self.cfg, self.overwrite))
        self.scene = read_scene(self.scene_path, downscale=self.cfg.downscale, split_seed=self.cfg.split_seed,
                                value_range=tuple(self.cfg.value_range), validation=self.cfg.validation,
                                allow_outside_links=self.cfg.allow_outside_links)
        self._scale_schedule()
        st = self.state
        t0 = time.perf_counter()
        if self.folder.resume_points():
            self._resume()
            self.log(f"resuming {self.out} at {st.phase.value} step {st.step}")
        elif self.from_stage1 is not None:
            def start():
                self._start_from_stage1(self.from_stage1)
                self._checkpoint()
            self._on_main(start)
            if not self.comm.is_main:  # the other ranks start from rank 0's first checkpoint
                self._resume()
        else:
            def setup():
                self.images = run_setup(st, self.scene, self.cfg, self.folder, self.progress, self.log)
                self._checkpoint()
            self._on_main(setup)
            if not self.comm.is_main:  # the other ranks start from rank 0's first checkpoint
                self._resume()
        if self.cfg.lambda_dense_depth > 0 and st.phase.trains_geometry:
            st.dense_depth = load_dense_depth(self.folder.out / "init", [f.name for f in self.scene.frames],
                                              self.scene.train_indices, self.scene.height, self.scene.width)
        self._write_status("running")
        try:
            with self._steps_finish_on_ctrl_c():
                self._run_phases()
        except KeyboardInterrupt:
            if self._aborted:  # mid-step: the last whole checkpoint stays the resume point
                self._write_status("interrupted")
                self.log("stopped at once: rerun the same command to resume from the last checkpoint")
                raise
            self._checkpoint()
            self._write_status("interrupted")
            self.log(f"interrupted: checkpoint saved at {st.phase.value} step {st.step}; rerun the same command to resume")
            raise
        st.timings["total_this_session"] = time.perf_counter() - t0
        path = self.folder.model
        if self.comm.is_main:
            with sigint_held(lambda: self.log("interrupt: writing the model first")):
                st.save_model(path)
                self._write_status("finished")
        self.comm.barrier()
        return path

    def _scale_schedule(self) -> None:
        """Train with the schedule scaled to the number of training views and the Gaussian cap to the
        image size when it is 0 (config.json keeps the options as given; checkpoints, the model file and
        run.json hold the values used)."""
        n_train = len(self.scene.train_indices)
        given = self.cfg
        self.cfg = with_gaussian_cap(scaled_schedule(given, n_train), self.scene.width, self.scene.height)
        self.state.cfg = self.cfg
        self.phases = run_plan(self.cfg)
        self.schedule = {"n_train_views": n_train, "ref_views": given.schedule_ref_views,
                         "scale": self.cfg.stage1_steps / given.stage1_steps if given.stage1_steps else 1.0,
                         "stage1_steps": self.cfg.stage1_steps, "stage2_steps": self.cfg.stage2_steps,
                         "refine_stop": self.cfg.strategy_config.refine_stop,
                         "max_gaussians_per_px": self.cfg.max_gaussians_per_px}

    def _run_phases(self) -> None:
        """Every phase left, each followed by its checkpoints and the next phase's set-up."""
        st = self.state
        while st.phase != Phase.DONE:
            tp = time.perf_counter()
            self._run_phase(st.phase, dict(self.phases)[st.phase])
            st.timings[st.phase.value] = st.timings.get(st.phase.value, 0.0) + time.perf_counter() - tp
            if st.phase == Phase.STAGE1 and self.comm.is_main:
                with sigint_held(self._hold_ctrl_c):
                    st.save_checkpoint(self.folder.stage1_ckpt)
            self._begin_phase(next_phase(self.phases, st.phase))
            self._checkpoint()

    @contextlib.contextmanager
    def _steps_finish_on_ctrl_c(self):
        """While the phases run, Ctrl-C (SIGINT) ends the run at the end of the current step, on every
        rank at the same step (the request is all-reduced with the step's losses), so that the
        checkpoint holds a whole step; a second Ctrl-C stops at once (the half-done step is not saved:
        the last checkpoint stays the resume point). Only in the main thread."""
        if threading.current_thread() is not threading.main_thread():
            yield
            return

        def handler(signum, frame):
            if self._ctrl_c:
                self._aborted = True
                raise KeyboardInterrupt
            self._ctrl_c = True
            self.log("interrupt: finishing the current step, then saving a checkpoint (Ctrl-C again to stop now)")

        previous = signal.signal(signal.SIGINT, handler)
        try:
            yield
        finally:
            signal.signal(signal.SIGINT, previous)

    def _set_threads(self) -> None:
        """The option ``threads``; 0 with several local ranks: the cores shared out among them."""
        n = self.cfg.threads
        if n <= 0 and self.comm.world > 1:
            local = int(os.environ.get("LOCAL_WORLD_SIZE", self.comm.world))
            n = max(1, (os.cpu_count() or 1) // max(local, 1))
        if n > 0:
            torch.set_num_threads(n)
            configure_threads(n)

    def _on_main(self, fn: Callable[[], None]) -> None:
        """Run ``fn`` on rank 0 only; its failure reaches every rank (a UserError as one, anything
        else as a RuntimeError on the other ranks) instead of leaving them waiting."""
        err, failure = None, None
        if self.comm.is_main:
            try:
                fn()
            except BaseException as exc:  # noqa: BLE001 - re-raised below, after telling the other ranks
                if self.comm.world == 1:
                    raise
                failure = exc
                err = ("user" if isinstance(exc, UserError) else "bug", str(exc))
        err = self.comm.broadcast_object(err)
        if failure is not None:
            raise failure
        if err is not None:
            raise UserError(err[1]) if err[0] == "user" else RuntimeError(f"rank 0 failed: {err[1]}")

    # -------------------------------------------------------------------------------- state
    def _train_images(self) -> TrainImages:
        if self.images is None:
            m = self.state.meta
            self.images = TrainImages(self.scene, self.state.stage1_bands(), m["cir_indices"], m["cir_scale"],
                                      self.cfg.cache_gib)
        return self.images

    def _checkpoint(self) -> None:
        """Save the resume state (the newest two are kept) and show the progress in run.json (rank 0);
        Ctrl-C during the save waits until it ends (:func:`sigint_held`)."""
        if not self.comm.is_main:
            return
        with sigint_held(self._hold_ctrl_c):
            self.state.save_checkpoint(self.folder.rotate_checkpoints())
            self._write_status("running")

    def _hold_ctrl_c(self) -> None:
        """Ctrl-C while a checkpoint is written: the run stops at the next step boundary."""
        self._ctrl_c = True
        self.log("interrupt: finishing the checkpoint first, then stopping at the end of the step")

    def _resume(self) -> None:
        """Continue from the newest resume checkpoint that loads (a damaged one is reported and
        skipped), and drop the log rows of the steps that will be repeated."""
        errors = []
        for path in self.folder.resume_points():
            try:
                tensors, meta = self.state.load_checkpoint(path)
            except UserError as exc:
                errors.append(str(exc))
                self.log(f"warning: skipping a damaged checkpoint: {exc}")
                continue
            self.state.load_training_state(tensors, meta)
            order = [p.value for p, _ in self.phases] + [Phase.DONE.value]
            at = (order.index(self.state.phase.value), self.state.step)
            if self.comm.is_main:
                self.folder.truncate_log(lambda ph, step: ph in order and (order.index(ph), step) <= at)
            return
        raise UserError("no checkpoint of this run can be read (" + "; ".join(errors) + "); "
                        "pass --overwrite to start again", file=self.folder.last_ckpt)

    def _start_from_stage1(self, path: Path) -> None:
        """A new run (another spectral variant or basis, this scene's fields) from the end of a decoupled
        run's stage 1: only the geometry comes from the checkpoint (:mod:`brfgs.train.from_stage1`)."""
        st = self.state

        def fit_decoder():
            t = time.perf_counter()
            fit_autoencoder(st, self.scene, self.cfg, self._train_images(), self.folder, self.progress, self.log)
            st.timings["autoencoder"] = time.perf_counter() - t

        start_from_stage1(st, self.scene, self.cfg, path, fit_decoder)
        self.folder.write_json("split.json", st.meta["scene"]["split"])
        self._begin_phase(Phase.STAGE2)

    def _begin_phase(self, phase: Phase) -> None:
        self.state.geometry_changed()
        if phase == Phase.STAGE2:
            init_head(self.state, self.cfg, self.scene, self._train_images())
        self.state.phase = phase
        self.state.step = 0

    def _write_status(self, status: str) -> None:
        if not self.comm.is_main:
            return
        st = self.state
        self.folder.write_status({"status": status, "phase": st.phase.value, "step": st.step,
                                  "config": self.cfg.to_dict(), "schedule": self.schedule,
                                  "scene": str(self.scene_path.resolve()),
                                  "timings_s": st.timings,
                                  "n_gaussians": st.gaussians.n if st.gaussians is not None else None,
                                  "learned_irradiance_scale": self._learned_scales(),
                                  "data_parallel": {"processes": self.comm.world, "views_per_step": self.cfg.views_per_step,
                                                    "allreduce_bytes_per_step": {k: v[0] / max(v[1], 1) for k, v in
                                                                                 self.comm_totals.items()}},
                                  "model": self.folder.model.name if status == "finished" else None})

    def _learned_scales(self) -> dict | None:
        """{training frame: learned irradiance scale} (option learn_irradiance), else None."""
        log_s = self.state.extra.get("log_irradiance")
        if log_s is None:
            return None
        names = [f["name"] for f in self.state.meta["scene"]["frames"]]
        return {names[i]: round(float(log_s[i].detach().exp()), 5) for i in self.scene.train_indices}

    # -------------------------------------------------------------------------------- a phase
    def _run_phase(self, phase: Phase, steps: int) -> None:
        st, c = self.state, self.cfg
        if st.decoder is not None:
            st.decoder.requires_grad_(bool(c.finetune_decoder and phase.fits_head))
        strategy = make_strategy(c, self.scene.width, self.scene.height, st.meta["extent_m"]) if phase.grows else None
        nbrs = None  # stage 2 (means frozen): each Gaussian's 8 nearest neighbours, for the normal smoothness
        if phase == Phase.STAGE2 and c.lambda_normal_smooth > 0 and "normals" in st.gaussians:
            nbrs = neighbours(st.gaussians.means)
        check_identical(self.comm, {**st.params(), "densify.grad2d": st.densify.grad2d}, f"{phase.value} step {st.step}")
        bar = tqdm(total=steps, initial=st.step, desc=phase.value, dynamic_ncols=True) if self.progress else None
        fh, writer = self.folder.open_log() if self.comm.is_main else (contextlib.nullcontext(), None)
        with fh:
            while st.step < steps:
                lv, ps = self._one_step(phase, steps, strategy, nbrs)
                self.history.append((phase.value, st.step, lv, ps))
                if writer is not None and (st.step % c.log_every == 0 or st.step == steps):
                    writer.writerow([phase.value, st.step, f"{lv:.6g}", f"{ps:.4f}", st.gaussians.n])
                    self._write_status("running")
                if bar is not None:
                    bar.update(1)
                    if st.step % 10 == 0:
                        bar.set_postfix(loss=f"{lv:.4f}", psnr=f"{ps:.2f}", n=st.gaussians.n)
                if st.step % c.checkpoint_every == 0 and st.step < steps:
                    if writer is not None:
                        fh.flush()
                    self._checkpoint()
                if self.callback is not None:
                    self.callback(phase.value, st.step)
                if self._stop_requested:
                    raise KeyboardInterrupt
        if bar is not None:
            bar.close()

    def _one_step(self, phase: Phase, steps: int, strategy: ADCStrategy | MCMCStrategy | None, nbrs) -> tuple[float, float]:
        """One optimisation step on ``views_per_step`` views (this rank's share of them); returns the
        step's mean (loss, psnr) over all its views."""
        st, c = self.state, self.cfg
        st.opt.lrs = learning_rates(c, phase, st.step, steps, st.meta["extent_m"],
                                    [k for k, _ in st.neural.named_parameters()] if st.neural is not None else (),
                                    [k for k, _ in st.decoder.named_parameters()] if st.decoder is not None else ())
        nv = c.views_per_step
        views = [pick_view(st, self.scene.train_indices, self.scene.width, self.scene.height, c, phase)
                 for _ in range(nv)]
        # one view per step draws its ray samples from the run's generator (as always); several
        # views each get a generator seeded from it, so that any rank can render any of them
        gens = [None] if nv == 1 else [torch.Generator().manual_seed(int(x))
                                       for x in torch.randint(0, 2**62, (nv,), generator=st.gen)]
        params = st.params()
        NamedAdam.zero_grad(params)
        stats = DensifyState(st.gaussians.n) if strategy is not None else None  # this step's statistics
        sums = torch.zeros(3, dtype=torch.float64)  # loss, psnr summed over this rank's views; Ctrl-C seen
        for (i, win), gen in shard(list(zip(views, gens)), self.comm):
            res = forward(st, c, phase, make_batch(st, self._train_images(), phase, i, win), steps, nbrs, gen=gen,
                          strategy=strategy)
            if strategy is not None:
                strategy.before_backward(res.out)
            (res.loss if nv == 1 else res.loss / nv).backward()
            if strategy is not None:
                strategy.after_backward(stats, res.out, win[2] if win else self.scene.width,
                                        win[3] if win else self.scene.height, grad_scale=nv)
            sums[:2] += torch.tensor([float(res.loss.detach()), res.psnr], dtype=torch.float64)
        sent = reduce_gradients(self.comm, params)  # bytes this rank all-reduced (0 in one process)
        if stats is not None:
            sent += self._merge_densify_stats(stats)
        sums[2] = float(self._ctrl_c)
        self.comm.all_reduce_(sums)
        self._stop_requested = bool(sums[2] > 0)
        tot = self.comm_totals.setdefault(phase.value, [0, 0])
        tot[0], tot[1] = tot[0] + sent, tot[1] + 1
        st.opt.step(params)
        st.step += 1
        if strategy is not None:
            strategy.after_step(st.gaussians, st.opt, st.densify, st.step, steps, st.gen)
        return float(sums[0]) / nv, float(sums[1]) / nv

    def _merge_densify_stats(self, stats: DensifyState) -> int:
        """Add the step's densification statistics, summed over the ranks, to the run's; returns the
        bytes this rank all-reduced."""
        n, sent = stats.grad2d.numel(), 0
        if self.comm.world > 1:
            flat = self.comm.all_reduce_(torch.cat([stats.grad2d, stats.count]))  # [2N]
            stats.grad2d, stats.count = flat[:n], flat[n:]
            sent = flat.numel() * flat.element_size()
        self.state.densify.grad2d += stats.grad2d
        self.state.densify.count += stats.count
        return sent


def train(scene_path, out_dir, cfg: TrainConfig, overwrite: bool = False, progress: bool = True, callback=None,
          from_stage1=None, log=print, comm: Comm | None = None) -> Path:
    """Train a model on ``scene_path`` into ``out_dir`` (resumes an unfinished run); returns model.safetensors.
    ``comm``: this process's rank of a data-parallel run (default: one process)."""
    trainer = Trainer(scene_path, out_dir, cfg, overwrite=overwrite, progress=progress, callback=callback,
                      from_stage1=from_stage1, log=log, comm=comm)
    # A Ctrl-C that lands inside a no_grad block's entry leaves grad mode off for good; enable_grad
    # restores the caller's mode on the way out, so a second train() in this process still learns.
    with torch.enable_grad():
        if not trainer.comm.is_main:
            return trainer.run()
        check_outside(Path(out_dir), Path(scene_path))  # before the lock creates the folder
        with folder_lock(Path(out_dir), "brfgs train"):  # one writer: the finished check and the run under it
            return trainer.run()


def train_rank(comm: Comm, scene_path, out_dir, cfg: TrainConfig, overwrite: bool, from_stage1, quiet: bool) -> None:
    """One rank of :func:`train_parallel` (module level: started by multiprocessing's spawn)."""
    train(scene_path, out_dir, cfg, overwrite=overwrite, progress=not quiet, from_stage1=from_stage1,
          log=None if quiet else print, comm=comm)


def train_parallel(nproc: int, scene_path, out_dir, cfg: TrainConfig, overwrite: bool = False,
                   from_stage1=None, quiet: bool = False) -> Path:
    """:func:`train` in ``nproc`` local processes (data-parallel, gloo; NCCL with GPUs); returns the
    path of model.safetensors, written by rank 0."""
    if nproc == 1:
        return train(scene_path, out_dir, cfg, overwrite, not quiet, from_stage1=from_stage1,
                     log=None if quiet else print)
    check_views_per_step(cfg.validate().views_per_step, nproc)  # before any process starts
    launch(nproc, train_rank, (Path(scene_path), Path(out_dir), cfg, overwrite, from_stage1, quiet))
    return RunFolder(out_dir).model


@contextlib.contextmanager
def sigint_held(on_press):
    """Hold Ctrl-C (SIGINT) off while the block runs (a checkpoint being written): a press calls
    ``on_press()`` instead of interrupting the write. Only in the main thread (elsewhere: no change)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, lambda signum, frame: on_press())
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
