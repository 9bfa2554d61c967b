"""Dataset generation: random scenes -> polarized renders -> synthetic captures -> samples.

One process renders a list of sample indices (a shard). Every sample is a pure function of the
run seed and its index (:func:`.scenegen.sample_seed`), so shards, resumed runs and reruns all
produce identical samples; writes are atomic (:mod:`pbrdf.data.dataset`), so a killed run resumes
without losing or duplicating work. Every run removes what killed runs left: the temporary
manifests of the dataset root and the temporary ``arrays/`` files of its shard (any run), and the
partial samples of its shard (``resume``: :func:`pbrdf.data.dataset.cleanup_partial`).

Instead of random scenes, ``GenerateConfig.scene`` renders one given scene spec (the Blender
add-on's exported scene). ``generate(..., spec_hook=...)`` passes every scene through a function
before rendering: the Blender route (``headless/render.py --via-blender``) lays the scene out in
Blender and exports it back there (:func:`blender_addon.build_spec.roundtrip_spec`).
"""

from __future__ import annotations

import io
import json
import logging
import platform
import time
import traceback
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from pbrdf.data import dataset
from pbrdf.data import sample as psample
from pbrdf.io.atomic import atomic_write_bytes, remove_leftovers
from pbrdf.sensor.rig import BUILTIN_PATTERNS, Rig
from pbrdf.sensor.rig_jitter import check_scale, draw_rig

from . import assets, mesh_corpus, passes, render, scenegen
from .asset_materials import usable_textured_assets
from .generated_shapes import GENERATED_SHAPES
from .procedural import PROCEDURAL_SHAPES
from .spec import SceneSpec
from .unseen_shapes import UNSEEN_SHAPES

__all__ = [
    "ARRAYS_DIR",
    "SHAPE_SETS",
    "VARIANT_ALIASES",
    "GenerateConfig",
    "GenerateInputs",
    "GenerateReport",
    "generate",
    "parse_objects",
    "render_sample",
    "versions",
    "write_arrays",
]

#: ``--shapes`` choices: built-in shape sets. ``procedural`` and ``generated`` are training shapes
#: (``train`` is both), ``meshes`` the unseen meshes of the ``test-meshes`` split, ``none`` no
#: built-in shape (asset files only).
SHAPE_SETS = {
    "procedural": PROCEDURAL_SHAPES,
    "generated": GENERATED_SHAPES,
    "train": PROCEDURAL_SHAPES + GENERATED_SHAPES,
    "meshes": UNSEEN_SHAPES,
    "none": (),
}

#: ``--variant`` aliases (:func:`.passes.choose_variant`); any ``*_polarized`` Mitsuba variant works too.
VARIANT_ALIASES = ("auto", "llvm", "cuda", "scalar")

#: Folder of a dataset holding the optional ``NNNNNN.npz`` copies of the samples (``--npz``).
ARRAYS_DIR = "arrays"

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class GenerateConfig:
    """What to generate (the flags of ``headless/render.py``; errors name fields, the script words them as flags)."""

    out: Path
    count: int
    resolution: int = 384
    seed: int = 0
    spp: int = 32
    assets: Path | None = None
    pbrdfs: Path | None = None
    rig: Path | None = None
    pattern: str | None = None
    resume: bool = False
    shard: tuple[int, int] = (0, 1)
    keep_stokes: bool = False
    keep_raw: bool = False
    noise: bool = True
    scene: Path | None = None
    npz: bool = False
    shapes: str | None = None
    split: str | None = None
    objects: tuple[int, int] = (1, 1)
    table_fraction: float | None = None
    variant: str = "auto"
    texture_fraction: float = 0.0
    asset_materials: bool = False
    distance: tuple[float, float] = (0.5, 1.0)
    rig_jitter: float = 0.0
    corpus: Path | None = None
    corpus_fraction: float = 0.0

    def __post_init__(self) -> None:
        """Check the fields; ``shapes`` None becomes ``none`` with ``assets``, else ``procedural``."""
        if self.count < 1:
            raise ValueError(f"count={self.count} must be >= 1")
        for name in ("assets", "pbrdfs", "rig", "scene"):
            p = getattr(self, name)
            if p is not None and not Path(p).exists():
                raise FileNotFoundError(f"{name}={p}: does not exist")
        if self.pattern is not None and self.pattern not in BUILTIN_PATTERNS and not Path(self.pattern).is_file():
            raise ValueError(f"pattern={self.pattern!r} must be one of {list(BUILTIN_PATTERNS)} or an image file")
        if self.shapes is None:
            object.__setattr__(self, "shapes", "none" if self.assets is not None else "procedural")
        if self.shapes not in SHAPE_SETS:
            raise ValueError(f"shapes={self.shapes!r} must be one of {sorted(SHAPE_SETS)}")
        if self.shapes == "none" and self.assets is None and self.scene is None:
            raise ValueError("shapes='none' leaves nothing to draw: give assets=DIR")
        if self.scene is not None and (self.assets is not None or self.pbrdfs is not None):
            raise ValueError("scene renders the given scene: it cannot be combined with assets or pbrdfs")
        object.__setattr__(self, "objects", parse_objects(self.objects))
        if self.scene is not None and (self.objects != (1, 1) or self.table_fraction is not None):
            raise ValueError("scene renders the given scene: it cannot be combined with objects or table_fraction")
        if self.table_fraction is not None:
            if not 0.0 <= self.table_fraction <= 1.0:
                raise ValueError(f"table_fraction={self.table_fraction} must be in [0, 1]")
            if self.table_fraction > 0 and self.pbrdfs is None:
                raise ValueError(f"table_fraction={self.table_fraction} > 0 needs pbrdfs=DIR (a pBRDF table library)")
        if not 0.0 <= self.texture_fraction <= 1.0:
            raise ValueError(f"texture_fraction={self.texture_fraction} must be in [0, 1]")
        if self.scene is not None and (self.texture_fraction > 0 or self.asset_materials):
            raise ValueError("scene renders the given scene: it cannot take texture_fraction or asset_materials")
        object.__setattr__(self, "rig_jitter", check_scale(self.rig_jitter))
        if not 0.0 <= self.corpus_fraction <= 1.0:
            raise ValueError(f"corpus_fraction={self.corpus_fraction} must be in [0, 1]")
        if (self.corpus_fraction > 0) != (self.corpus is not None):
            raise ValueError("corpus_fraction > 0 and corpus=DIR (a mesh corpus folder) go together")
        if self.scene is not None and (self.rig_jitter > 0 or self.corpus is not None):
            raise ValueError("scene renders the given scene: it cannot take rig_jitter or corpus")
        if self.variant not in VARIANT_ALIASES and not self.variant.endswith("_polarized"):
            valid = f"one of {list(VARIANT_ALIASES)} or a *_polarized Mitsuba variant"
            raise ValueError(f"variant={self.variant!r} must be {valid}")

    def load_inputs(self) -> GenerateInputs:
        """Read and check the files the fields name: rig and pattern, the given scene, asset files, pBRDF tables.

        Returns:
            What every sample of the run draws from, and the render settings (with the Mitsuba
            variant chosen for ``variant``).

        Raises:
            ValueError: a pattern the display refuses, an invalid scene, an asset folder without
                usable mesh files, a variant this machine cannot run, bad render settings.
        """
        rig = Rig.load(self.rig) if self.rig else Rig()
        if self.pattern is not None:  # the display's pattern only: the scenes stay those of the seed
            try:
                rig = replace(rig, display=replace(rig.display, pattern=self.pattern))
            except ValueError as e:
                raise ValueError(f"pattern={self.pattern!r}: {e}") from None
        fixed = SceneSpec.load(self.scene) if self.scene else None
        if fixed is not None:
            if self.rig:
                fixed = replace(fixed, rig=rig)
            try:
                fixed.validate()
            except ValueError as e:
                raise ValueError(f"scene={self.scene}: {e}") from None
        asset_files = self._asset_files()
        materials = scenegen.load_material_library(self.pbrdfs) if self.pbrdfs else None
        try:
            variant = passes.choose_variant(self.variant)
        except RuntimeError as e:
            raise ValueError(f"variant={self.variant!r}: {e}") from None
        settings = render.RenderSettings(resolution=self.resolution, spp=self.spp, noise=self.noise, variant=variant)
        corpus = mesh_corpus.corpus_files(self.corpus) if self.corpus is not None else None
        return GenerateInputs(rig, fixed, asset_files, materials, settings, corpus)

    def _asset_files(self) -> list[Path] | None:
        """The usable mesh files of ``assets`` (None without it); files the pipeline refuses are left out."""
        if not self.assets:
            return None
        files = assets.list_assets(self.assets)
        if not files:
            raise ValueError(f"assets={self.assets}: no {'/'.join(s[1:].upper() for s in assets.MESH_SUFFIXES)} files")
        # The same pool for every shard and rerun.
        files, refused = (usable_textured_assets if self.asset_materials else assets.usable_assets)(files)
        if refused:
            log.warning("assets=%s: %d of %d files refused and left out", self.assets, len(refused),
                        len(refused) + len(files))  # fmt: skip
            for why in refused.values():
                log.warning("asset left out: %s", why)
        if not files:
            first = next(iter(refused.values()))
            raise ValueError(f"assets={self.assets}: every file was refused (first: {first})")
        return files

    def scene_args(self) -> dict:
        """The scene-content settings recorded in every sidecar when they differ from the single-object defaults."""
        args = {}
        if self.objects != (1, 1):
            args["objects_range"] = list(self.objects)
        if self.table_fraction is not None:
            args["table_fraction"] = self.table_fraction
        if self.texture_fraction > 0:
            args["texture_fraction"] = self.texture_fraction
        if self.asset_materials:
            args["asset_materials"] = True
        if tuple(self.distance) != (0.5, 1.0):
            args["distance_range"] = list(self.distance)
        if self.corpus_fraction > 0:
            args["corpus_fraction"] = self.corpus_fraction
        return args


@dataclass(frozen=True)
class GenerateInputs:
    """What a run draws its samples from, loaded and checked once (:meth:`GenerateConfig.load_inputs`).

    Attributes:
        rig: the display-camera rig (with ``pattern`` applied).
        fixed: the given scene (``scene``), or None for random scenes.
        asset_files: the usable mesh files of ``assets``, or None.
        materials: the pBRDF table library of ``pbrdfs``, or None.
        settings: the render settings (resolution, spp, noise, the chosen Mitsuba variant).
        corpus: the usable meshes of ``corpus`` (:func:`.mesh_corpus.corpus_files`), or None.
    """

    rig: Rig
    fixed: SceneSpec | None
    asset_files: list[Path] | None
    materials: list | None
    settings: render.RenderSettings
    corpus: list[Path] | None = None


def parse_objects(value: str | int | tuple[int, int]) -> tuple[int, int]:
    """``objects``: ``"N"``, ``"MIN-MAX"``, an int or a pair -> ``(min, max)`` with ``1 <= min <= max``.

    Example:
        >>> parse_objects("2-4"), parse_objects("3"), parse_objects((1, 1))
        ((2, 4), (3, 3), (1, 1))
    """
    try:
        if isinstance(value, str):
            parts = value.split("-")
            lo, hi = (int(parts[0]), int(parts[-1])) if 1 <= len(parts) <= 2 else (0, -1)
        elif isinstance(value, (int, np.integer)) and not isinstance(value, bool):
            lo = hi = int(value)
        else:
            lo, hi = (int(v) for v in value)
    except (TypeError, ValueError):
        lo, hi = 0, -1
    if not 1 <= lo <= hi:
        raise ValueError(f"objects={value!r} must be N or MIN-MAX with 1 <= MIN <= MAX")
    return lo, hi


@dataclass
class GenerateReport:
    """Outcome of a run: written, skipped (already complete) and failed samples, with timings."""

    written: list[int] = field(default_factory=list)
    skipped: int = 0
    failed: dict[int, str] = field(default_factory=dict)
    seconds: list[float] = field(default_factory=list)
    stage_seconds: dict[str, float] = field(default_factory=dict)

    def summary(self) -> str:
        """A few lines for the terminal."""
        lines = [f"written {len(self.written)}, skipped {self.skipped} (already complete), failed {len(self.failed)}"]
        if self.seconds:
            s = np.asarray(self.seconds)
            lines.append(f"seconds per sample: mean {s.mean():.2f}, median {np.median(s):.2f}, max {s.max():.2f}")
            total = sum(self.stage_seconds.values()) or 1.0
            parts = ", ".join(f"{k} {v / len(s):.2f}s ({100 * v / total:.0f}%)" for k, v in self.stage_seconds.items())
            lines.append(f"per stage: {parts}")
        for i, why in sorted(self.failed.items())[:10]:
            lines.append(f"  sample {i}: {why}")
        return "\n".join(lines)


def versions() -> dict[str, str]:
    """Software versions recorded in every sidecar and manifest."""
    out = {"python": platform.python_version(), "numpy": np.__version__}
    for mod in ("mitsuba", "drjit", "trimesh"):
        try:
            out[mod] = __import__(mod).__version__
        except Exception:  # noqa: BLE001 - a missing optional package is simply not listed
            pass
    return out


def render_sample(
    spec: SceneSpec,
    settings: render.RenderSettings,
    *,
    sample_seed: int,
    noise: bool = True,
    keep_stokes: bool = False,
    keep_raw: bool = False,
    decode_model=None,
) -> tuple[dict, dict, dict[str, float]]:
    """Render one scene spec into a dataset sample: polarized render, camera model, decode.

    The camera noise is drawn from ``numpy.random.default_rng([sample_seed, 1])``; the render's
    own seeds come from ``spec.seed``. The Blender add-on calls this too, so its in-process
    render equals ``headless/render.py --scene`` with the same seeds. ``decode_model`` is the
    camera model the decoder assumes (default: the spec's, :func:`.render.synthesize_sample`).

    Returns:
        ``(sample, metadata, seconds)``: the :mod:`pbrdf.data.dataset` sample, its sidecar metadata
        and the wall time of the stages ``render`` and ``camera+decode``.
    """
    t0 = time.perf_counter()
    result = render.render_stokes(spec, settings)
    t1 = time.perf_counter()
    sample, meta = render.synthesize_sample(
        spec, result, rng=np.random.default_rng([sample_seed, 1]), noise=noise, keep_stokes=keep_stokes,
        keep_raw=keep_raw, decode_model=decode_model,
    )  # fmt: skip
    return sample, meta, {"render": t1 - t0, "camera+decode": time.perf_counter() - t1}


def write_arrays(root: str | Path, index: int, sample: dict, meta: dict) -> Path:
    """Write a sample's arrays as ``root/arrays/NNNNNN.npz`` (numpy only), atomically.

    For readers without OpenEXR (Blender's Python): keys are the sample's arrays, plus
    ``map_names`` (the nine maps' names) and ``metadata`` (the sidecar metadata as JSON).
    """
    from pbrdf.sensor.decode import NINE_MAP_NAMES  # noqa: PLC0415

    buf = io.BytesIO()
    arrays = {k: np.asarray(v) for k, v in sample.items() if k != "raw"}
    np.savez_compressed(
        buf, **arrays, map_names=np.asarray(NINE_MAP_NAMES), metadata=np.asarray(json.dumps(meta, default=str))
    )
    path = Path(root) / ARRAYS_DIR / f"{index:06d}.npz"
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, buf.getvalue())
    return path


def _array_in_shard(name: str, shard: tuple[int, int]) -> bool:
    """Whether ``name`` is the ``arrays/`` file (``NNNNNN.npz``) of a sample of ``shard``."""
    stem, dot, ext = name.partition(".")
    return dot == "." and ext == "npz" and stem.isdigit() and int(stem) % shard[1] == shard[0]


def generate(
    cfg: GenerateConfig,
    *,
    progress: bool = True,
    spec_hook: Callable[[SceneSpec], SceneSpec] | None = None,
) -> GenerateReport:
    """Render ``cfg.count`` samples (this process's shard of them) into ``cfg.out``.

    Args:
        cfg: what to generate.
        progress: show a progress bar.
        spec_hook: applied to every scene spec before rendering (the Blender route); the
            sidecar records the spec it returns.
    """
    inputs = cfg.load_inputs()
    out = Path(cfg.out)
    info = _run_info(cfg, inputs, spec_hook)
    _check_same_scenes(out, info)
    todo = dataset.plan_work(out, cfg.count, cfg.shard, cfg.resume)
    if cfg.resume:
        dataset.cleanup_partial(out, shard=cfg.shard)
    dataset.remove_manifest_leftovers(out)
    remove_leftovers(out / ARRAYS_DIR, lambda name: _array_in_shard(name, cfg.shard))
    report = GenerateReport(skipped=len(dataset.shard_indices(cfg.count, cfg.shard)) - len(todo))
    bar = None
    if progress:
        from tqdm import tqdm  # noqa: PLC0415

        bar = tqdm(total=len(todo), desc=f"render shard {cfg.shard[0]}/{cfg.shard[1]}", unit="sample")
    for index in todo:
        t0 = time.perf_counter()
        try:
            stages = _write_one(cfg, inputs, index, info, spec_hook)
        except Exception as exc:  # noqa: BLE001 - one bad sample must not stop a long run
            report.failed[index] = f"{type(exc).__name__}: {exc}"
            log.debug("sample %d failed:\n%s", index, traceback.format_exc())
        else:
            report.written.append(index)
            report.seconds.append(time.perf_counter() - t0)
            for k, v in stages.items():
                report.stage_seconds[k] = report.stage_seconds.get(k, 0.0) + v
        if bar is not None:
            bar.set_postfix(failed=len(report.failed))
            bar.update()
    if bar is not None:
        bar.close()
    dataset.write_manifest(out, info)
    return report


#: The manifest's ``config`` fields that decide what a sample holds: a run adding to a folder must match them.
SCENE_FIELDS = ("resolution", "seed", "spp", "shapes", "objects", "table_fraction", "texture_fraction",
                "asset_materials", "pattern", "noise", "keep_raw", "split", "distance", "rig_jitter",
                "corpus_fraction", "corpus_digest")  # fmt: skip
#: Scene fields added after the first manifests, with the value every run before them had.
_FIELDS_BEFORE = {"texture_fraction": 0.0, "asset_materials": False, "distance": [0.5, 1.0], "rig_jitter": 0.0,
                  "corpus_fraction": 0.0, "corpus_digest": None}  # fmt: skip


def _check_same_scenes(out: Path, info: dict) -> None:
    """Refuse to add samples to a dataset whose manifest was written with other scene settings.

    A split whose definition changed (e.g. textures added) would otherwise mix two kinds of samples
    in one folder on ``resume``. Fields a manifest lacks (older runs) are not compared, except
    those of :data:`_FIELDS_BEFORE`, which had their value there.
    """
    try:
        old = dataset.read_manifest(out).get("config") or {}
    except FileNotFoundError:
        return
    old = {**_FIELDS_BEFORE, **old} if old else old
    new = json.loads(json.dumps(info["config"], default=str))  # as the manifest stores it (tuples as lists)
    differ = [f"{k}={old[k]!r} there, {new[k]!r} now" for k in SCENE_FIELDS if k in old and old[k] != new.get(k)]
    if differ:
        raise ValueError(f"{out}: its samples were made with other settings ({'; '.join(differ)}); "
                         "render into a new folder")  # fmt: skip


def _run_info(cfg: GenerateConfig, inputs: GenerateInputs, spec_hook: Callable | None) -> dict:
    """The manifest's record of the run: sizes, settings, rig, software versions, variant, split, scene content."""
    info = {
        "count": cfg.count,
        "resolution": cfg.resolution,
        "seed": cfg.seed,
        "spp": cfg.spp,
        "config": {k: (str(v) if isinstance(v, Path) else v) for k, v in asdict(cfg).items()},
        "rig": inputs.rig.to_dict(),
        "versions": versions(),
        "variant": inputs.settings.variant,
    }
    # The corpus listing decides the scenes; its folder may differ between machines, its digest may not.
    info["config"]["corpus_digest"] = mesh_corpus.corpus_digest(inputs.corpus, cfg.corpus) if inputs.corpus else None
    if cfg.split is not None:
        info["split"] = cfg.split
    info.update(cfg.scene_args())
    if spec_hook is not None:
        info["spec_hook"] = f"{spec_hook.__module__}.{spec_hook.__qualname__}"
    return info


def _write_one(
    cfg: GenerateConfig, inputs: GenerateInputs, index: int, info: dict, spec_hook: Callable | None
) -> dict[str, float]:
    """Draw, render and write sample ``index``; returns the seconds of its stages (scene, render, decode, write)."""
    t0 = time.perf_counter()
    seed = scenegen.sample_seed(cfg.seed, index)
    if inputs.fixed is not None:
        spec = inputs.fixed
    else:
        spec = scenegen.random_scene(
            inputs.rig, seed, asset_files=inputs.asset_files, materials=inputs.materials,
            shapes=SHAPE_SETS[cfg.shapes], objects=cfg.objects, table_fraction=cfg.table_fraction,
            asset_materials=cfg.asset_materials, texture_fraction=cfg.texture_fraction, distance=tuple(cfg.distance),
            corpus_files=inputs.corpus, corpus_fraction=cfg.corpus_fraction,
        )  # fmt: skip
    drawn = None
    if cfg.rig_jitter > 0:  # rendered and simulated through the drawn rig, decoded with the nominal one
        rig, drawn = draw_rig(inputs.rig, seed, cfg.rig_jitter)
        spec = replace(spec, rig=rig)
    if spec_hook is not None:
        spec = spec_hook(spec)
    t1 = time.perf_counter()
    sample, meta, stages = render_sample(
        spec, inputs.settings, sample_seed=seed, noise=cfg.noise, keep_stokes=cfg.keep_stokes, keep_raw=cfg.keep_raw,
        decode_model=None if drawn is None else inputs.rig.camera.model,
    )  # fmt: skip
    meta.update(sample_seed=seed, run_seed=cfg.seed, versions=info["versions"], spec=spec.to_dict())
    if drawn is not None:  # "rig" is what the decoder (and a user) assumes; spec.rig the drawn one
        meta.update(rig=inputs.rig.to_dict(), rig_jitter=drawn)
    if cfg.split is not None:
        meta["split"] = cfg.split
    meta.update(cfg.scene_args())
    t3 = time.perf_counter()
    psample.write_sample(cfg.out, index, sample, meta)
    if cfg.npz:
        write_arrays(cfg.out, index, sample, meta)
    t4 = time.perf_counter()
    t2 = t1 + stages["render"]
    return {"scene": t1 - t0, "render": t2 - t1, "camera+decode": t3 - t2, "write": t4 - t3}
