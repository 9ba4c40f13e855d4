"""``brfgs demo [OUT]``: simulate a small scene, run the whole pipeline, evaluate, report."""

from __future__ import annotations

import json
import time
from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    @app.command("demo")
    def demo_cmd(
        out: Path = typer.Argument(Path("brfgs-demo"), help="Folder for the demo's scene, runs and report."),
        size: int = typer.Option(64, "--size", help="Simulated image size (px)."),
        views: int = typer.Option(25, "--views", help="Simulated views (13, 25, 37 or 49)."),
        bands: int = typer.Option(164, "--bands", help="Simulated bands over 350-1000 nm."),
        spp: int = typer.Option(16, "--spp", help="Simulation samples per pixel (a power of 4)."),
        stage1_steps: int = typer.Option(None, "--stage1-steps", help="Override the fast preset's stage-1 steps."),
        stage2_steps: int = typer.Option(None, "--stage2-steps", help="Override the fast preset's stage-2 steps."),
        threads: int = typer.Option(0, "--threads", help="CPU threads (0 = all)."),
        quiet: bool = typer.Option(False, "--quiet", help="No progress bars."),
    ) -> None:
        """Simulate -> select bands -> initialise -> autoencoder -> stage 1 -> stage 2 -> evaluate, BRF-GS vs SH."""
        from brfgs.train.config import preset
        from brfgs.train.evaluate import evaluate_run, summary_lines
        from brfgs.train.trainer import STAGE1_CKPT, train

        say = (lambda *a: None) if quiet else typer.echo
        t0 = time.perf_counter()
        out.mkdir(parents=True, exist_ok=True)
        scene = out / "scene"
        if not (scene / "transforms.json").is_file():
            from brfgs.sim import SimConfig, simulate

            say(f"[1/4] simulating a {size}x{size} testsite scene, {views} views, {bands} bands -> {scene}")
            simulate(scene, SimConfig(scene="testsite", size=size, views=views, bands=bands, spp=spp),
                     progress=not quiet)
        else:
            say(f"[1/4] using the simulated scene in {scene}")
        t_sim = time.perf_counter() - t0
        over = {"threads": threads}
        if stage1_steps is not None:
            over["stage1_steps"] = stage1_steps
        if stage2_steps is not None:
            over["stage2_steps"] = stage2_steps
        cfg = preset("fast", **over)
        say("[2/4] training BRF-GS (bands -> init -> autoencoder -> stage 1 -> stage 2)")
        brf = out / "brfgs"
        train(scene, brf, cfg, progress=not quiet, log=say) if not _finished(brf) else None
        say("[3/4] training the SH baseline on the same stage-1 geometry")
        sh = out / "sh_baseline"
        from dataclasses import replace

        if not _finished(sh):
            train(scene, sh, replace(cfg, variant="sh"), progress=not quiet, from_stage1=brf / STAGE1_CKPT, log=say)
        say("[4/4] evaluating the test views")
        res_b = evaluate_run(brf, scene, backend=cfg.backend, progress=not quiet)
        res_s = evaluate_run(sh, scene, backend=cfg.backend, progress=not quiet)
        total = time.perf_counter() - t0
        against = "truth" if "truth" in res_b["against"] else "observed"
        mb, ms = res_b["against"][against]["mean"], res_s["against"][against]["mean"]
        lines = ["", "BRF-GS demo report", "==================",
                 f"scene: {scene} ({res_b['scene']}, {len(res_b['split']['train'])} train / "
                 f"{len(res_b['split']['test'])} test views)",
                 *summary_lines(res_b), *summary_lines(res_s)]
        better = (mb["psnr"] or -1) > (ms["psnr"] or 1e9) and (mb["sam"] or 1e9) < (ms["sam"] or -1)
        lines.append(f"BRF-GS vs SH baseline against {against}: PSNR {mb['psnr'] - ms['psnr']:+.2f} dB, "
                     f"SAM {100 * (mb['sam'] - ms['sam']) / ms['sam']:+.1f}% -> "
                     + ("BRF-GS is better on both" if better else "BRF-GS is NOT better on both"))
        ae = res_b["settings"].get("autoencoder") or {}
        if ae:
            lines.append(f"spectral autoencoder (d={cfg.latent_dim}) on test pixels: SAM {ae['sam_mean_rad']:.4f} rad, "
                         f"RMSE {ae['rmse']:.5f}")
        lines += ["", "outputs:",
                  f"  scene (ENVI cubes, truth/)       {scene}",
                  f"  BRF-GS model                     {brf / 'model.safetensors'}",
                  f"  BRF-GS metrics                   {brf / 'metrics.json'}",
                  f"  BRF-GS test renders (ENVI)       {brf / 'eval' / 'renders'}",
                  f"  CIR comparisons + error maps     {brf / 'eval' / 'cir'}",
                  f"  band selection / init            {brf / 'bands.json'}  {brf / 'init'}",
                  f"  SH baseline run                  {sh}",
                  f"time: {total / 60:.1f} min (simulation {t_sim / 60:.1f} min)"]
        report = "\n".join(lines)
        (out / "report.txt").write_text(report + "\n")
        (out / "report.json").write_text(json.dumps({"brfgs": res_b["against"], "sh": res_s["against"],
                                                     "seconds": total, "simulation_seconds": t_sim}, indent=1))
        typer.echo(report)
        typer.echo(f"report: {out / 'report.txt'}")


def _finished(run: Path) -> bool:
    p = run / "run.json"
    return p.is_file() and json.loads(p.read_text()).get("status") == "finished"
