"""piezopreload: design and tuning studies for feed drives with piezo-actuated ball-screw preload.

The application layer: the command line, study files, the pipeline and artifact I/O. The
physics lives in :mod:`piezopreload.models`, identification and tuning in
:mod:`piezopreload.tuning`.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("piezopreload")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0+unknown"
