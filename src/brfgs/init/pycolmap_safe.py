"""pycolmap, imported so that it leaves the process as it found it.

- pycolmap 4.2.1 breaks Python's ``zlib`` when it is imported first (``np.savez_compressed`` and
  PNG writing then abort with "free(): invalid pointer"): ``zlib`` is imported before it.
- pycolmap installs glog's failure-signal handler, which also catches SIGTERM and prints a native
  stack trace: a rank that the ``torch.distributed`` launcher stops, or a run stopped by ``kill``,
  then looks like a crash. SIGTERM is given back its previous handler.

Every module that needs pycolmap does ``from brfgs.init.pycolmap_safe import pycolmap``.
"""

import zlib  # noqa: F401  (must precede pycolmap)
import signal
import threading

_term = signal.getsignal(signal.SIGTERM)

import pycolmap  # noqa: E402

if threading.current_thread() is threading.main_thread() and _term is not None:
    signal.signal(signal.SIGTERM, _term)  # Python's record is still the handler before pycolmap's

__all__ = ["pycolmap"]
