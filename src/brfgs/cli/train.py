"""``brfgs train`` / ``brfgs evaluate`` / ``brfgs ablate``: two-stage BRF-GS training and its evaluation."""

from __future__ import annotations

from pathlib import Path

import typer


def _config(preset: str, **opts):
    from brfgs.train.config import preset as make

    over = {k: v for k, v in opts.items() if v is not None}
    if "value_range" in over:
        from brfgs.cli._options import parse_value_range

        over["value_range"] = parse_value_range(over["value_range"])
    if "components" in over:
        over["components"] = tuple(c.strip() for c in over["components"].split(",") if c.strip())
    return make(preset, **over)


def register(app: typer.Typer) -> None:
    @app.command("train")
    def train_cmd(
        scene: Path = typer.Argument(..., help="Scene folder (transforms.json + images/)."),
        out: Path = typer.Argument(..., help="Run folder (created; an unfinished run there is resumed)."),
        preset: str = typer.Option("fast", "--preset", help="fast (CPU minutes), paper (GPU-scale), tiny (tests)."),
        variant: str = typer.Option(None, "--variant", help="brf (BRF-GS), sh (SH-3 latent), neural (MS-Splatting-style), cir (3DGS on CIR)."),
        joint: bool = typer.Option(None, "--joint/--decoupled", help="Train geometry and reflectance at once (Table 4 ablation)."),
        components: str = typer.Option(None, "--components", help="Hybrid kernel terms, e.g. iso,vol,geo,spec."),
        latent_dim: int = typer.Option(None, "--latent-dim", help="Spectral latent size d (<= 32)."),
        stage1_steps: int = typer.Option(None, "--stage1-steps", help="Stage-1 steps."),
        stage2_steps: int = typer.Option(None, "--stage2-steps", help="Stage-2 steps."),
        downscale: int = typer.Option(None, "--downscale", help="Integer area-average factor applied when reading."),
        value_range: str = typer.Option(None, "--value-range", metavar="LO,HI", help="Plausible reflectance range (default -0.5,10)."),
        band_strategy: str = typer.Option(None, "--band-strategy", help="Band selection strategy (brfgs select-bands)."),
        poses: str = typer.Option(None, "--poses", help="known | sfm | auto."),
        finetune_decoder: bool = typer.Option(None, "--finetune-decoder/--frozen-decoder", help="Optimise the spectral decoder in stage 2."),
        lambda_normal: float = typer.Option(None, "--lambda-normal", help="Weight of the depth-normal consistency loss while geometry trains (0 = off; default 0.05)."),
        lambda_flat: float = typer.Option(None, "--lambda-flat", help="Weight of the flatness loss (smallest/largest scale) while geometry trains (0 = off; default 0.01)."),
        lambda_depth_conc: float = typer.Option(None, "--lambda-depth-conc", help="Weight of the ray-wise depth concentration loss (surface prior; sharper depth maps, lower PSNR) while geometry trains (0 = off, default)."),
        lambda_depth_smooth: float = typer.Option(None, "--lambda-depth-smooth", help="Weight of the edge-aware second-order smoothness of the rendered inverse depth while geometry trains (0 = off; default 50)."),
        lr_spec: float = typer.Option(None, "--lr-spec", help="Adam learning rate of the specular latent z_spec (default 0.2; the other latents use 0.01)."),
        learn_normals: bool = typer.Option(None, "--learn-normals/--geometric-normals", help="Learn per-Gaussian shading normals in stage 2 (default) or use the smallest axis (paper)."),
        stage1_cir_bands: bool = typer.Option(None, "--stage1-cir-bands/--stage1-selected-bands-only", help="Stage 1 also fits the CIR bands (default; not in the paper) or only the selected bands."),
        lambda_normal_smooth: float = typer.Option(None, "--lambda-normal-smooth", help="Weight of the stage-2 smoothness loss of the learned normals over 8 neighbours (0 = off; default 0.1)."),
        stage1_sh_degree: int = typer.Option(None, "--stage1-sh-degree", help="View dependence of the stage-1 colours: SH degree 0 (none) to 3 (default 3, as 3DGS)."),
        max_gaussians_per_px: float = typer.Option(None, "--max-gaussians-per-px", help="Cap densification at this many Gaussians per image pixel (0 = no cap)."),
        backend: str = typer.Option(None, "--backend", help="Rasterizer: auto | torch | cpu | cuda."),
        threads: int = typer.Option(None, "--threads", help="CPU threads (0 = all)."),
        seed: int = typer.Option(None, "--seed", help="Seed of every random choice."),
        checkpoint_every: int = typer.Option(None, "--checkpoint-every", help="Steps between checkpoints."),
        from_stage1: Path = typer.Option(None, "--from-stage1", help="Start stage 2 from another run's checkpoints/stage1.safetensors."),
        evaluate: bool = typer.Option(True, "--evaluate/--no-evaluate", help="Evaluate the test views after training."),
        overwrite: bool = typer.Option(False, "--overwrite", help="Replace a finished run in OUT."),
        quiet: bool = typer.Option(False, "--quiet", help="No progress bars."),
    ) -> None:
        """Train BRF-GS (or a baseline) on SCENE into OUT; rerun to resume; Ctrl-C keeps a checkpoint."""
        from brfgs.train.trainer import train

        cfg = _config(preset, variant=variant, joint=joint, components=components, latent_dim=latent_dim,
                      stage1_steps=stage1_steps, stage2_steps=stage2_steps, downscale=downscale,
                      value_range=value_range, band_strategy=band_strategy, poses=poses, finetune_decoder=finetune_decoder, backend=backend,
                      lambda_normal=lambda_normal, lambda_flat=lambda_flat, lambda_depth_conc=lambda_depth_conc, lambda_depth_smooth=lambda_depth_smooth, lr_spec=lr_spec, learn_normals=learn_normals, lambda_normal_smooth=lambda_normal_smooth, stage1_cir_bands=stage1_cir_bands, stage1_sh_degree=stage1_sh_degree, max_gaussians_per_px=max_gaussians_per_px,
                      threads=threads, seed=seed, checkpoint_every=checkpoint_every)
        path = train(scene, out, cfg, overwrite=overwrite, progress=not quiet, from_stage1=from_stage1,
                     log=(lambda *a: None) if quiet else typer.echo)
        typer.echo(f"model: {path}")
        if evaluate:
            from brfgs.train.evaluate import evaluate_run, summary_lines

            res = evaluate_run(out, scene, backend=cfg.backend, progress=not quiet)
            for line in summary_lines(res):
                typer.echo(line)
            typer.echo(f"metrics: {out / 'metrics.json'}")

    @app.command("evaluate")
    def evaluate_cmd(
        out: Path = typer.Argument(..., help="Run folder of brfgs train."),
        scene: Path = typer.Option(None, "--scene", help="Scene folder (default: the one recorded in the model)."),
        backend: str = typer.Option("auto", "--backend", help="Rasterizer backend."),
        images: bool = typer.Option(True, "--images/--no-images", help="Write ENVI renders and CIR PNGs."),
        quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
    ) -> None:
        """Render every test view; write OUT/metrics.json, ENVI renders and CIR comparison PNGs."""
        from brfgs.train.evaluate import evaluate_run, summary_lines

        res = evaluate_run(out, scene, backend=backend, write_images=images, progress=not quiet)
        for line in summary_lines(res):
            typer.echo(line)
        typer.echo(f"metrics: {out / 'metrics.json'}")
        if images:
            typer.echo(f"renders: {out / 'eval' / 'renders'}  CIR comparisons: {out / 'eval' / 'cir'}")

    @app.command("ablate")
    def ablate_cmd(
        scene: Path = typer.Argument(..., help="Scene folder."),
        out: Path = typer.Argument(..., help="Folder for the study's runs and tables."),
        study: str = typer.Option(..., "--study", help="kernels (Table 3) | training (Table 4) | bands (Table 2) | baselines (Table 1)."),
        preset: str = typer.Option("fast", "--preset", help="Training preset of every run."),
        stage1_steps: int = typer.Option(None, "--stage1-steps"),
        stage2_steps: int = typer.Option(None, "--stage2-steps"),
        latent_dim: int = typer.Option(None, "--latent-dim"),
        downscale: int = typer.Option(None, "--downscale"),
        value_range: str = typer.Option(None, "--value-range", metavar="LO,HI"),
        threads: int = typer.Option(None, "--threads"),
        backend: str = typer.Option(None, "--backend"),
        quiet: bool = typer.Option(False, "--quiet"),
    ) -> None:
        """Train the variants of one of the paper's tables on SCENE and write OUT/table_<study>.{md,csv}."""
        from brfgs.train.ablate import ablate

        cfg = _config(preset, stage1_steps=stage1_steps, stage2_steps=stage2_steps, latent_dim=latent_dim,
                      downscale=downscale, value_range=value_range, threads=threads, backend=backend)
        res = ablate(scene, out, study, cfg, progress=not quiet, log=(lambda *a: None) if quiet else typer.echo)
        typer.echo(Path(res["paths"]["md"]).read_text())
        typer.echo(f"tables: {res['paths']['md']}  {res['paths']['csv']}")
