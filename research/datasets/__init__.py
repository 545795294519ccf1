"""Mitsuba ground-truth datasets: built-in scenes, the generator and the loader.

    from research.datasets import DatasetConfig, generate, load
    generate(DatasetConfig("objects", views=100, res=256, spp=64), "data/objects")
    ds = load("data/objects"); train = ds.load_split("train")   # verified against manifest.json
"""

from research.datasets.generate import (CACHE_ROOT_HELP, DatasetConfig, cache_dir, ensure, generate,
                                       provenance)
from research.datasets.loader import (Dataset, DatasetError, FlowSequence, Protocol, StereoPair, load, load_flow,
                                      load_stereo)
from research.datasets.blender import load_blender
from research.datasets.colmap import load_colmap
from research.datasets.formats import FORMATS, detect_format, open_dataset
from research.datasets.scenes import SCENES, SceneSpec, get_scene
from research.datasets.integrity import verify

__all__ = ["CACHE_ROOT_HELP", "DatasetConfig", "cache_dir", "ensure", "generate", "provenance", "Dataset",
           "DatasetError", "FlowSequence", "Protocol", "StereoPair", "load_blender", "load_colmap",
           "FORMATS", "detect_format", "open_dataset", "load", "load_flow", "load_stereo", "SCENES", "SceneSpec",
           "get_scene", "verify"]
