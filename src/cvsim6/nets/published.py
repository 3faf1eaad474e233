"""The paper's published networks, converted into this project's model files.

The authors published every trained network of the paper (MIT licence) in their
repository :data:`ORIGIN_REPOSITORY`, folder ``Model/CVSIM6/``, at commit
:data:`ORIGIN_COMMIT`: plain PyTorch state_dicts (float64) plus the standardization
of inputs and outputs (``X-mu.csv``, ``X-std.csv``, ``Y-mu.csv``, ``Y-std.csv``).
:func:`fetch_published_networks` downloads them and checks every SHA-256;
:func:`convert_published_study` writes the same files the training rules write
(``emulator.pt``, ``flow_delta<d>.pt``, ``encoder_decoder_delta<d>.pt``), so every
downstream rule and ``cvsim6 invert --models`` use them unchanged.

Facts the conversion relies on (checked where they can be):

* layer layout: the authors' ``MLP_nonlinear`` is ``Linear, act, [Linear, act] * (L - 2),
  Linear`` like :class:`cvsim6.nets.MLP`, so ``nn.Sequential`` indices carry over;
  their Real-NVP alternates ``coupling, [batch norm]`` from data to latent, block 0
  transforming the second half (our ``swap=False``), batch norm with eps 1e-5 and the
  running statistics used in eval mode, as :class:`cvsim6.nets.RealNVP`;
  the encoder's output is ``[mean, log-variance]`` like ours; the base distribution
  must be N(0, I) (``NF.Base_mean`` = 0, ``NF.Base_var`` = 1: checked).
* units: SVR and PVR are in Wood units (mmHg min/L) in these networks' output
  standardization; the registry uses dyn s/cm^5 (x :data:`cvsim6.registry.WOOD_TO_DYN`).
  Scaling those two entries of the output mean and std by 80 leaves the standardized
  values, hence the networks, unchanged. LVEF is a fraction in both.
* noise: in the noisy EHR folders the output std includes the injected noise,
  ``sqrt(std^2 + (delta s)^2)``: it is the standardization those flows and
  encoder/decoders were trained with, so it is kept as theirs.
"""
from __future__ import annotations

import logging
import re
from pathlib import Path

import numpy as np
import torch

from cvsim6.data.downloads import check_sha256, download_checked
from cvsim6.nets import Emulator, EncoderDecoder, RealNVP, save_model
from cvsim6.registry import N_OUTPUTS, N_PARAMETERS, OUTPUT_INDEX, WOOD_TO_DYN

log = logging.getLogger(__name__)

#: Public origin of the networks.
ORIGIN_REPOSITORY = "desResLab/InVAErt4Cardio"
ORIGIN_COMMIT = "92260f8b5037ecdc5818d6c8725e5d01fddfbe05"
ORIGIN_FOLDER = "Model/CVSIM6"

#: Folder of each study's networks, relative to :data:`ORIGIN_FOLDER` (EHR: per noise level).
STRUCTURAL_FOLDER = "Structural_id_study"
EHR_EMULATOR_FOLDER = "EHR/NoiseFreeEmulator"
EHR_NOISE_LEVELS = (0.25, 0.5, 1.0, 2.0)
#: Folder of each study's emulator.
EMULATOR_FOLDER_BY_STUDY = {"structural": STRUCTURAL_FOLDER, "ehr": EHR_EMULATOR_FOLDER}
#: The noise level of the structural study's networks (trained on noise-free data).
STRUCTURAL_NOISE_LEVELS = (0.0,)

SCALER_FILES = ("X-mu.csv", "X-std.csv", "Y-mu.csv", "Y-std.csv")

#: SHA-256 of every file used, by path relative to :data:`ORIGIN_FOLDER`.
SHA256: dict[str, str] = {
    "EHR/NoiseFreeEmulator/Emulator_model.pth": "5c55a8f2a383b3b5c9f389394efa41e6e5cb90a2ffcd9b5e9a7052df3ed0c296",
    "EHR/NoiseFreeEmulator/X-mu.csv": "56d827200eea2f79790990de4d14b08f938f67b830d45ec7670573bfb433e103",
    "EHR/NoiseFreeEmulator/X-std.csv": "6f0cd5f983cae3049ee4e4d977c5e0ebfb34533d736e68033befc62a9c62ecf5",
    "EHR/NoiseFreeEmulator/Y-mu.csv": "c9773e5e80d07370e0b5edaa7a1b6415855b87aa264408d807e8bd03c611837e",
    "EHR/NoiseFreeEmulator/Y-std.csv": "f75c4bb12b39dd329e53442d03849c0f1f6b2e119df282b980478aa8697175b8",
    "EHR/noise-level=0.25/Inverse_model.pth": "7acada12f24145bf731ec0eb4eb9ba140ad5b2086a54310787864b621fd8a620",
    "EHR/noise-level=0.25/NF_model.pth": "21be374c1f1e7d964abad9a1de568f420401cb14d1467e023bd5194205d36e7c",
    "EHR/noise-level=0.25/X-mu.csv": "56d827200eea2f79790990de4d14b08f938f67b830d45ec7670573bfb433e103",
    "EHR/noise-level=0.25/X-std.csv": "6f0cd5f983cae3049ee4e4d977c5e0ebfb34533d736e68033befc62a9c62ecf5",
    "EHR/noise-level=0.25/Y-mu.csv": "c9773e5e80d07370e0b5edaa7a1b6415855b87aa264408d807e8bd03c611837e",
    "EHR/noise-level=0.25/Y-std.csv": "8c702f364ebdb108ffbdbf538540090fc69e046b9bde7b956c2c3de9bf68253e",
    "EHR/noise-level=0.5/Inverse_model.pth": "ad968e5b3897c195887a4da4260b29517c78aa3ca2299f45aa2a89636fda4629",
    "EHR/noise-level=0.5/NF_model.pth": "ae1f3f55e3e55faff1e45343b8f1f2963e08703e5651063184417d46ede29a45",
    "EHR/noise-level=0.5/X-mu.csv": "56d827200eea2f79790990de4d14b08f938f67b830d45ec7670573bfb433e103",
    "EHR/noise-level=0.5/X-std.csv": "6f0cd5f983cae3049ee4e4d977c5e0ebfb34533d736e68033befc62a9c62ecf5",
    "EHR/noise-level=0.5/Y-mu.csv": "c9773e5e80d07370e0b5edaa7a1b6415855b87aa264408d807e8bd03c611837e",
    "EHR/noise-level=0.5/Y-std.csv": "969c792fe0ce5fd387502a8ea429953bc773fdca938a87975f313f2221450193",
    "EHR/noise-level=1.0/Inverse_model.pth": "04f1272c2ea03dd0cd7cf2df89bf652fb5e3f468e73b8fca31cf5e78053f0313",
    "EHR/noise-level=1.0/NF_model.pth": "b9e3020d04623393d54601be93561c83ecec90e8e8e74cd73783b6754ef12361",
    "EHR/noise-level=1.0/X-mu.csv": "56d827200eea2f79790990de4d14b08f938f67b830d45ec7670573bfb433e103",
    "EHR/noise-level=1.0/X-std.csv": "6f0cd5f983cae3049ee4e4d977c5e0ebfb34533d736e68033befc62a9c62ecf5",
    "EHR/noise-level=1.0/Y-mu.csv": "c9773e5e80d07370e0b5edaa7a1b6415855b87aa264408d807e8bd03c611837e",
    "EHR/noise-level=1.0/Y-std.csv": "f6bc979cca09ed819358313cb0de77df894ada2b6b060d0a15e0959261a0ea1d",
    "EHR/noise-level=2.0/Inverse_model.pth": "4ac128002b7c9106932a8331955cb2fccbadcf6e6503cdf06bb3e6dfccb96b79",
    "EHR/noise-level=2.0/NF_model.pth": "3f9b1761e9bbca9d48ab4d063cb22378e45f1842cd34f67060d14f4ef054fd40",
    "EHR/noise-level=2.0/X-mu.csv": "56d827200eea2f79790990de4d14b08f938f67b830d45ec7670573bfb433e103",
    "EHR/noise-level=2.0/X-std.csv": "6f0cd5f983cae3049ee4e4d977c5e0ebfb34533d736e68033befc62a9c62ecf5",
    "EHR/noise-level=2.0/Y-mu.csv": "c9773e5e80d07370e0b5edaa7a1b6415855b87aa264408d807e8bd03c611837e",
    "EHR/noise-level=2.0/Y-std.csv": "879f22c6ff04485baac12e00f9757ca580985c5f2358b058d6701d83cb696d44",
    "Structural_id_study/Emulator_model.pth": "bdde2338ffcb81cc67c35ff841edf20a8ddd4a0589ac050b8e6edada2e7126f1",
    "Structural_id_study/Inverse_model.pth": "ac10af1b913d25dcbcc1545483ebebe988f263b787530471ea6f28493fcf705b",
    "Structural_id_study/NF_model.pth": "76c88470854bde1220a1503cada8fd5eb468fe5a9e50cd488ffe947cb70a0532",
    "Structural_id_study/X-mu.csv": "0d7fd7710b64b9810b5a889f0554421be3c0f98b46d1ac3d9d4fe5880edd7b60",
    "Structural_id_study/X-std.csv": "d09b9947c636a58d16702ac66cdef061508bb8021bf22938426cf0035330b994",
    "Structural_id_study/Y-mu.csv": "ef8048a0e788a8a10f6b72bbe8f7f0f4e2ad1701a5e11a768caa0ec7621b09f3",
    "Structural_id_study/Y-std.csv": "4b78d7913c4e883c77ac86d1d6d2cdc6714b2f0c6227c564f424b5e15d02256b",
}


class PublishedNetworkError(ValueError):
    """A published network file does not have the layout the conversion expects."""


def noise_folder(delta: float) -> str:
    """Folder of the EHR networks trained at noise level ``delta``, e.g. ``EHR/noise-level=0.5``."""
    if float(delta) not in EHR_NOISE_LEVELS:
        raise PublishedNetworkError(f"no published EHR networks for noise level {delta:g}; "
                                    f"the paper published {', '.join(f'{d:g}' for d in EHR_NOISE_LEVELS)}")
    return f"EHR/noise-level={float(delta)}"


def study_files(study: str, noise_levels=None) -> list[str]:
    """Relative paths of the published files behind ``study``'s networks.

    ``noise_levels`` (EHR only; default all four) selects the noisy folders.
    """
    if study == "structural":
        if noise_levels is not None and [float(d) for d in noise_levels] != list(STRUCTURAL_NOISE_LEVELS):
            raise PublishedNetworkError(f"the published structural networks are for noise level 0 only, "
                                        f"not {list(noise_levels)}")
        names = ["Emulator_model.pth", "NF_model.pth", "Inverse_model.pth", *SCALER_FILES]
        return [f"{STRUCTURAL_FOLDER}/{n}" for n in names]
    if study == "ehr":
        deltas = EHR_NOISE_LEVELS if noise_levels is None else noise_levels
        files = [f"{EHR_EMULATOR_FOLDER}/{n}" for n in ("Emulator_model.pth", *SCALER_FILES)]
        for d in deltas:
            files += [f"{noise_folder(d)}/{n}" for n in ("NF_model.pth", "Inverse_model.pth", *SCALER_FILES)]
        return files
    raise ValueError(f"unknown study {study!r}; 'structural' or 'ehr'")


def origin_url(relpath: str, base_url: str | None = None) -> str:
    """Public URL of one published file (``=`` in folder names URL-encoded)."""
    base = base_url or (f"https://raw.githubusercontent.com/{ORIGIN_REPOSITORY}/{ORIGIN_COMMIT}/{ORIGIN_FOLDER}")
    return f"{base.rstrip('/')}/{relpath.replace('=', '%3D')}"


def fetch_published_networks(directory: str, base_url: str | None = None) -> None:
    """Workflow step: download every published file (:data:`SHA256`) into ``directory``,
    same relative layout, each checked against its SHA-256; ``base_url`` replaces the
    pinned origin (a mirror)."""
    for rel, sha in SHA256.items():
        download_checked(origin_url(rel, base_url), sha, Path(directory) / rel,
                         what=f"published network file {rel}, commit {ORIGIN_COMMIT[:12]}",
                         local_key="networks.published.path")


def verify_published_files(directory: str | Path, files: list[str]) -> None:
    """Check every ``directory/<relpath>`` in ``files`` against :data:`SHA256`: a missing or
    altered file raises :class:`cvsim6.data.downloads.ChecksumError` naming it and the expected digest."""
    for rel in files:
        check_sha256(Path(directory) / rel, SHA256[rel],
                     what=f"published network file {rel}, commit {ORIGIN_COMMIT[:12]}")


# ----------------------------------------------------------------------------- conversion
def _read_vector(path: Path, n: int) -> np.ndarray:
    x = np.loadtxt(path, dtype=np.float64, ndmin=1)
    if x.shape != (n,) or not np.isfinite(x).all():
        raise PublishedNetworkError(f"{path}: expected {n} finite values, got shape {x.shape}")
    return x


def read_scalers(folder: str | Path) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """``((x_mean, x_std), (y_mean, y_std))`` of a published folder, registry units
    (SVR and PVR converted from Wood units to dyn s/cm^5)."""
    folder = Path(folder)
    x = (_read_vector(folder / "X-mu.csv", N_PARAMETERS), _read_vector(folder / "X-std.csv", N_PARAMETERS))
    y_mean, y_std = _read_vector(folder / "Y-mu.csv", N_OUTPUTS), _read_vector(folder / "Y-std.csv", N_OUTPUTS)
    for name in ("SVR", "PVR"):
        j = OUTPUT_INDEX[name]
        y_mean[j] *= WOOD_TO_DYN
        y_std[j] *= WOOD_TO_DYN
    return x, (y_mean, y_std)


def _load_state(path: Path) -> dict[str, torch.Tensor]:
    state = torch.load(path, map_location="cpu", weights_only=True)
    if not isinstance(state, dict):
        raise PublishedNetworkError(f"{path}: expected a state_dict, got {type(state).__name__}")
    return state


def _sub_state(state: dict, prefix: str, path: Path) -> dict[str, torch.Tensor]:
    """Entries under ``prefix.`` with the prefix removed."""
    sub = {k[len(prefix) + 1:]: v for k, v in state.items() if k.startswith(prefix + ".")}
    if not sub:
        raise PublishedNetworkError(f"{path}: no keys under {prefix!r} (keys: {sorted(state)[:5]} ...)")
    return sub


def _mlp_shape(sub: dict[str, torch.Tensor], path: Path) -> tuple[int, int, int, int]:
    """``(n_in, n_out, hidden, n_linear_layers)`` of an ``nn.Sequential`` MLP state."""
    idx = sorted(int(m.group(1)) for k in sub if (m := re.fullmatch(r"(\d+)\.weight", k)))
    if not idx or idx != list(range(0, 2 * len(idx), 2)):
        raise PublishedNetworkError(f"{path}: Linear layers expected at even indices, found {idx}")
    first, last = sub[f"{idx[0]}.weight"], sub[f"{idx[-1]}.weight"]
    return first.shape[1], last.shape[0], first.shape[0], len(idx)


def _set_scaler(scaler, mean: np.ndarray, std: np.ndarray) -> None:
    scaler.mean.copy_(torch.as_tensor(mean, dtype=scaler.mean.dtype))
    scaler.std.copy_(torch.as_tensor(std, dtype=scaler.std.dtype))


def _load_into(model: torch.nn.Module, state: dict[str, torch.Tensor], path: Path) -> None:
    """Load weights (float64, as published) into ``model``, keeping its scalers; every
    published tensor must find its place and every weight of ``model`` must be given."""
    model.to(torch.float64)
    own = {k for k in model.state_dict() if "_scaler." not in k}
    missing, unexpected = own - set(state), set(state) - own
    if missing or unexpected:
        raise PublishedNetworkError(f"{path}: weights do not match the {model.kind} architecture "
                                    f"(missing {sorted(missing)[:4]}, unexpected {sorted(unexpected)[:4]})")
    model.load_state_dict(state, strict=False)


def convert_emulator(weights: str | Path, folder: str | Path) -> Emulator:
    """The published ``Emulator_model.pth`` with the scalers of ``folder``, as an :class:`Emulator`."""
    path = Path(weights)
    sub = _sub_state(_load_state(path), "model_emulator", path)
    n_in, n_out, hidden, layers = _mlp_shape(sub, path)
    if (n_in, n_out) != (N_PARAMETERS, N_OUTPUTS):
        raise PublishedNetworkError(f"{path}: emulator maps {n_in} -> {n_out}, expected 23 -> 16")
    emu = Emulator(hidden=hidden, layers=layers)
    _load_into(emu, {f"net.{k}": v for k, v in sub.items()}, path)
    (xm, xs), (ym, ys) = read_scalers(folder)
    _set_scaler(emu.x_scaler, xm, xs)
    _set_scaler(emu.y_scaler, ym, ys)
    return emu.eval()


def convert_flow(weights: str | Path, folder: str | Path) -> RealNVP:
    """The published ``NF_model.pth`` with the output scaler of ``folder``, as a :class:`RealNVP`."""
    path = Path(weights)
    state = _load_state(path)
    base_mean, base_var = state.get("NF.Base_mean"), state.get("NF.Base_var")
    if base_mean is None or base_var is None or not (torch.all(base_mean == 0) and torch.all(base_var == 1)):
        raise PublishedNetworkError(f"{path}: the flow's base distribution is not N(0, I)")
    sub = _sub_state(state, "NF.real_nvp_nf_net", path)
    layer_ids = sorted({int(k.split(".")[0]) for k in sub})
    couplings = [i for i in layer_ids if f"{i}.s.0.weight" in sub]
    norms = [i for i in layer_ids if f"{i}.log_gamma" in sub]
    batchnorm = bool(norms)
    expected = (list(range(0, 2 * len(couplings), 2)), list(range(1, 2 * len(couplings), 2))) if batchnorm \
        else (list(range(len(couplings))), [])
    if (couplings, norms) != expected:
        raise PublishedNetworkError(f"{path}: expected couplings alternating with batch norms, "
                                    f"found couplings at {couplings}, batch norms at {norms}")
    s0 = {k[len("0.s."):]: v for k, v in sub.items() if k.startswith("0.s.")}
    _, _, hidden, layers = _mlp_shape(s0, path)
    dim = int(sub["0.s.0.weight"].shape[1] + sub[f"0.s.{2 * (layers - 1)}.weight"].shape[0])
    if dim != N_OUTPUTS:
        raise PublishedNetworkError(f"{path}: flow of dimension {dim}, expected {N_OUTPUTS}")
    flow = RealNVP(dim=dim, hidden=hidden, blocks=len(couplings), layers_per_block=layers, batchnorm=batchnorm)
    _load_into(flow, {f"layers.{k}": v for k, v in sub.items()}, path)
    _, (ym, ys) = read_scalers(folder)
    _set_scaler(flow.y_scaler, ym, ys)
    return flow.eval()


def convert_encoder_decoder(weights: str | Path, folder: str | Path) -> EncoderDecoder:
    """The published ``Inverse_model.pth`` with the scalers of ``folder``, as an :class:`EncoderDecoder`."""
    path = Path(weights)
    state = _load_state(path)
    enc, dec = _sub_state(state, "VAE_encoder", path), _sub_state(state, "Decoder", path)
    e_in, e_out, e_hidden, e_layers = _mlp_shape(enc, path)
    d_in, d_out, d_hidden, d_layers = _mlp_shape(dec, path)
    latent = e_out // 2
    if e_in != N_PARAMETERS or d_out != N_PARAMETERS or e_out != 2 * latent or d_in != N_OUTPUTS + latent:
        raise PublishedNetworkError(f"{path}: encoder {e_in} -> {e_out}, decoder {d_in} -> {d_out} do not "
                                    f"fit 23 parameters, 16 outputs and a latent space of {latent}")
    ed = EncoderDecoder(latent_dim=latent, encoder_hidden=e_hidden, encoder_layers=e_layers,
                        decoder_hidden=d_hidden, decoder_layers=d_layers)
    _load_into(ed, {**{f"encoder.{k}": v for k, v in enc.items()},
                    **{f"decoder.{k}": v for k, v in dec.items()}}, path)
    (xm, xs), (ym, ys) = read_scalers(folder)
    _set_scaler(ed.x_scaler, xm, xs)
    _set_scaler(ed.y_scaler, ym, ys)
    return ed.eval()


def _info(rel: str) -> dict:
    return {"source": "published", "origin": origin_url(rel), "commit": ORIGIN_COMMIT, "sha256": SHA256[rel]}


def convert_published_study(directory: str, study: str, emulator: str, flows: list[str],
                            encoder_decoders: list[str], noise_levels: list[float]) -> None:
    """Workflow step: verify the published files of ``study`` in ``directory`` and write
    them as this project's model files: ``emulator`` and, per noise level (same order as
    ``noise_levels``), ``flows[i]`` and ``encoder_decoders[i]``."""
    if isinstance(flows, str):
        flows, encoder_decoders = [flows], [encoder_decoders]
    if not (len(flows) == len(encoder_decoders) == len(noise_levels)):
        raise ValueError("one flow and one encoder/decoder output per noise level")
    files = study_files(study, noise_levels)
    verify_published_files(directory, files)
    root = Path(directory)
    emu_folder = EMULATOR_FOLDER_BY_STUDY[study]
    rel = f"{emu_folder}/Emulator_model.pth"
    save_model(convert_emulator(root / rel, root / emu_folder), emulator, info=_info(rel))
    for delta, flow_out, ed_out in zip(noise_levels, flows, encoder_decoders):
        folder = STRUCTURAL_FOLDER if study == "structural" else noise_folder(delta)
        rel = f"{folder}/NF_model.pth"
        save_model(convert_flow(root / rel, root / folder), flow_out, info={**_info(rel), "noise_level": delta})
        rel = f"{folder}/Inverse_model.pth"
        save_model(convert_encoder_decoder(root / rel, root / folder), ed_out,
                   info={**_info(rel), "noise_level": delta})
        log.info("%s, delta=%g: converted %s", study, delta, folder)
