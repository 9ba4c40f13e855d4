"""Scores of a trained model: metrics.py (PSNR/SSIM/LPIPS on CIR, SAM; lpips_net.py), evaluate.py
(a run's held-out views: metrics.json, renders), by_material.py (accuracy per simulator material),
compare.py / compare_scenes.py (two runs, or pairs of runs over scenes, with bootstrap intervals)."""
