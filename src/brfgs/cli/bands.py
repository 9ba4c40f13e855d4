"""``brfgs select-bands SCENE``: geometry-reliable band selection (EFC, paper eqs 3–8) and Table 2 strategies."""

from __future__ import annotations

from pathlib import Path

import typer

from brfgs.bands.options import SelectBandsOptions
from brfgs.cli import _options as opt
from brfgs.cli._config import apply_options, config_command

# The command bodies import the library lazily, so that `brfgs --help` stays fast (no torch, no numba).


def select_bands_cmd(scene: Path, options: dict) -> None:
    """Rank the bands by equivalent feature count (EFC) and keep the top k; write bands.json and a plot."""
    from brfgs.bands import plot_band_stats, select_bands
    from brfgs.data import atomic

    o = apply_options(SelectBandsOptions(), options).validate()
    sc = opt.read_scene(scene, o.read)
    out = o.out if o.out is not None else Path.cwd() / f"bands_{sc.name}"
    opt.check_output_dir(out, sc.root, overwrite=o.overwrite, marker="bands.json")
    sel = select_bands(sc, o.strategy, top=o.top, detect_max_px=o.detect_max_px, detect_max_mpx=o.detect_max_mpx,
                       progress=not o.quiet,
                       with_stats=True, min_separation_nm=o.min_separation_nm)
    out.mkdir(parents=True, exist_ok=True)
    atomic.write_json(out / "bands.json", sel.to_json())
    plot_band_stats(sel, out / "bands.png")
    typer.echo(format_selection(sel))
    typer.echo(f"\nwrote {out / 'bands.json'} and {out / 'bands.png'}")


def format_selection(sel, n_rows: int = 10) -> str:
    """Text table of the selected bands and the EFC ranking."""
    import numpy as np

    st = sel.stats
    lines = [f"strategy {sel.strategy}: selected "
             + (", ".join(f"{sel.wavelengths_nm[i]:.1f} nm (band {i})" for i in sel.selected)
                if len(sel.selected) <= 12 else f"{len(sel.selected)} bands")]
    if st is None:
        return lines[0]
    if st.detect_downscale > 1:
        lines.append(f"(features detected on images downscaled by {st.detect_downscale})")
    lines.append(f"{'rank':>4} {'band':>5} {'nm':>8} {'EFC':>10} {'features':>9} {'sigma':>9} {'SNR':>9}")
    order = np.lexsort((np.arange(len(st.efc_mean)), -st.efc_mean))
    for r, i in enumerate(order[:n_rows]):
        mark = " *" if i in sel.selected else ""
        lines.append(f"{r + 1:>4} {i:>5} {st.wavelengths_nm[i]:>8.1f} {st.efc_mean[i]:>10.2f} "
                     f"{st.features_mean[i]:>9.1f} {st.sigma[i]:>9.2g} {st.snr[i]:>9.1f}{mark}")
    return "\n".join(lines)


def register(app: typer.Typer) -> None:
    @config_command(app, "select-bands", SelectBandsOptions)
    def command(scene: Path = opt.SceneArg, options: dict | None = None) -> None:
        """Rank the bands by equivalent feature count (EFC) and keep the top k; write bands.json and a plot.

        Per band and view: SIFT keypoints on the band as an 8-bit image (eq. 3), 5x5 median reflectance
        around each (eq. 4) over the dark-frame sigma (eq. 5), normalised by the scene-wide maximum (eq. 6),
        summed (eq. 7), averaged over views, top k (eq. 8).
        """
        select_bands_cmd(scene, options)
