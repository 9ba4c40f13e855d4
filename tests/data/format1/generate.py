import sys
from pathlib import Path
sys.path.insert(0, "/tmp/ref/src/tests")
from test_train_scene import make_plane_scene
from brfgs.train.presets import preset
from brfgs.train.trainer import train
import brfgs, torch
print(brfgs.__file__, brfgs.__version__)
torch.set_num_threads(1)
root = Path(sys.argv[1])
scene = make_plane_scene(root / "scene", w=48, h=32, n_bands=8, n_views=13)
cfg = preset("tiny", threads=1, stage1_steps=12, stage2_steps=6, ae_steps=40, init_fill_points=150,
             checkpoint_every=5, backend="torch")
train(scene, root / "finished", cfg, progress=False, log=None)
def stop(phase, step):
    if (phase, step) == ("stage1", 8):
        raise KeyboardInterrupt
try:
    train(scene, root / "interrupted", cfg, progress=False, log=None, callback=stop)
except KeyboardInterrupt:
    print("interrupted")
