"""A full-size X20P cube (1886×1886×164 float32, 2.3 GB, sparse on disk) read with downscale 8
stays under 1 GB peak resident memory: the reader never holds the full cube."""

import json
import subprocess
import sys
import textwrap

import numpy as np

from brfgs.data.cameras import Intrinsics, pose_from_view_angles

H = W = 1886
B = 164


def test_full_resolution_cube_downscaled_under_1gb(tmp_path):
    root = tmp_path / "big"
    (root / "images").mkdir(parents=True)
    wl = np.linspace(350, 1000, B)
    frames = []
    for k in range(3):
        name = f"v{k}"
        hdr = (f"ENVI\nsamples = {W}\nlines = {H}\nbands = {B}\nheader offset = 0\nfile type = ENVI Standard\n"
               f"data type = 4\ninterleave = bip\nbyte order = 0\nwavelength units = Nanometers\n"
               f"wavelength = {{{', '.join(f'{w:.4f}' for w in wl)}}}\n")
        (root / "images" / f"{name}.hdr").write_text(hdr)
        with open(root / "images" / f"{name}.img", "wb") as f:  # sparse: all zeros, no disk blocks
            f.truncate(H * W * B * 4)
        frames.append({"file_path": f"images/{name}.hdr",
                       "transform_matrix": pose_from_view_angles(20.0 * k, 0.0, 100.0).tolist()})
    intr = Intrinsics.from_fov(35.0, W, H)
    (root / "transforms.json").write_text(json.dumps({
        "fl_x": intr.fl_x, "fl_y": intr.fl_y, "cx": intr.cx, "cy": intr.cy, "w": W, "h": H,
        "wavelengths_nm": wl.tolist(), "sun_zenith_deg": 30.0, "sun_azimuth_deg": 120.0,
        "dark_sigma": [0.01] * B, "frames": frames}))
    # Peak RSS of a fresh process that reads the cube: VmHWM of its own address space. (Not ru_maxrss: Linux
    # carries it across exec, so a child spawned by a large pytest process inherits the parent's peak.)
    code = textwrap.dedent(f"""
        import numpy as np
        from brfgs.data import read_scene
        sc = read_scene({str(root)!r}, downscale=8)
        img = sc.load_image(1)
        assert img.shape == ({H // 8}, {W // 8}, {B}) and float(np.abs(img).max()) == 0.0
        print(next(int(l.split()[1]) for l in open('/proc/self/status') if l.startswith('VmHWM:')))
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    peak_mib = int(out.stdout.strip().splitlines()[-1]) / 1024
    print(f"peak resident memory {peak_mib:.0f} MiB")
    assert peak_mib < 1024
