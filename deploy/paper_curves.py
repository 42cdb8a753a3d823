#!/usr/bin/env python3
"""Write the MBPO authors' learning curves as CSV for `mbpo plot` (common/report/data/).

The authors (Janner et al. 2019) shared their TensorFlow runs' curves of the paper's Figure 2 as
pickles `<task>_mbpo.pkl` with keys x (env steps in thousands), y (mean eval return over seeds)
and std (over seeds), read by their `plot.py`. Their Drive link is not reachable from here; the
same files, with that `plot.py`, are in facebookresearch/svg at commit c05887e (removed later):

    git clone https://github.com/facebookresearch/svg && cd svg
    git checkout c05887ea6f15863915eced1b03019bb011b9657d -- data/mbpo
    python3 deploy/paper_curves.py svg/data/mbpo > common/report/data/mbpo-authors-curves.csv

The pickles hold numpy arrays. This reads them without numpy and without running any code from
the file: the unpickler accepts only numpy's array and dtype classes and decodes the raw
little-endian float64 buffer itself.
"""
import pickle
import struct
import sys
from pathlib import Path

# Pickle name -> the Gymnasium task name ours uses (the authors ran v2 on MuJoCo 1.5; their Ant
# is AntTruncatedObs-v2: no contact forces in the observation, as our Ant-v5 config).
TASKS = {
    "hopper": ("Hopper", "Hopper-v2"),
    "walker2d": ("Walker2d", "Walker2d-v2"),
    "cheetah": ("HalfCheetah", "HalfCheetah-v2"),
    "ant": ("Ant", "AntTruncatedObs-v2"),
}


class _Dtype:
    def __init__(self, *args):
        self.args = args

    def __setstate__(self, state):
        self.state = state


class _Array:
    def __init__(self, *args):
        self.values = []

    def __setstate__(self, state):
        _version, shape, dtype, _fortran, raw = state
        if dtype.args[0] != "f8":
            raise ValueError(f"expected float64 arrays, found dtype {dtype.args[0]!r}")
        count = 1
        for d in shape:
            count *= d
        self.values = list(struct.unpack(f"<{count}d", raw))


class _NumpyArraysOnly(pickle.Unpickler):
    def find_class(self, module, name):
        if name == "_reconstruct":
            return lambda *args: _Array()
        if (module, name) == ("numpy", "ndarray"):
            return _Array
        if (module, name) == ("numpy", "dtype"):
            return _Dtype
        raise pickle.UnpicklingError(f"refusing to load {module}.{name}: only numpy arrays")


def main() -> None:
    if len(sys.argv) != 2:
        sys.exit("usage: paper_curves.py DIR_WITH_<task>_mbpo.pkl > mbpo-authors-curves.csv")
    src = Path(sys.argv[1])
    print("# The MBPO authors' TF runs (Janner et al. 2019, Figure 2): mean and std over seeds of")
    print("# the eval return (1 deterministic episode per 1000-step epoch), from <task>_mbpo.pkl in")
    print("# facebookresearch/svg@c05887ea6f15863915eced1b03019bb011b9657d data/mbpo.")
    print("# Written by deploy/paper_curves.py; tasks are v2 on MuJoCo 1.5 (`source` column).")
    print("task,source,env_steps,mean,std")
    for pickle_name, (task, source) in TASKS.items():
        with open(src / f"{pickle_name}_mbpo.pkl", "rb") as f:
            data = _NumpyArraysOnly(f, encoding="latin1").load()
        xs, ys, stds = (data[k].values for k in ("x", "y", "std"))
        if not len(xs) == len(ys) == len(stds):
            sys.exit(f"{pickle_name}: x, y and std differ in length")
        for x, y, s in zip(xs, ys, stds):
            print(f"{task},{source},{round(x * 1000)},{y:.1f},{s:.1f}")


if __name__ == "__main__":
    main()
