"""Training hyperparameters (cvsim6.training.hyperparameters): checks and defaults."""
from __future__ import annotations

import re

import pytest

from cvsim6.training import hyperparameters as hp

from training_helpers import EMU, FLOW, ENCDEC, RESTARTS, SCREEN


def test_hyper_validation():
    with pytest.raises(ValueError, match="missing"):
        hp.check_hyper("emulator", {k: v for k, v in EMU.items() if k != "lr"})
    with pytest.raises(ValueError, match="unknown"):
        hp.check_hyper("flow", FLOW | {"hiden": 3})
    with pytest.raises(ValueError, match="reduction"):
        hp.check_hyper("encoder_decoder", ENCDEC | {"reduction": "max"})
    with pytest.raises(ValueError, match="lr_step"):
        hp.check_hyper("emulator", {k: v for k, v in EMU.items() if k != "lr_step"})
    with pytest.raises(ValueError, match="reeval_target"):
        hp.check_hyper("encoder_decoder", ENCDEC | {"reeval_target": "exact"})
    with pytest.raises(ValueError, match="dtype"):
        hp.check_hyper("emulator", EMU | {"dtype": "float16"})
    with pytest.raises(ValueError, match="warmup_epochs"):
        hp.check_hyper("emulator", EMU | {"lr_schedule": "cosine", "warmup_epochs": EMU["epochs"]})
    for bad in (0.0, -1e-3, True, "1e-3", float("nan")):
        with pytest.raises(ValueError, match="variance_floor"):
            hp.check_hyper("emulator", EMU | {"variance_floor": bad})
    with pytest.raises(ValueError, match="unknown"):  # an emulator option only
        hp.check_hyper("flow", FLOW | {"variance_floor": 1e-3})
    for bad in (-0.1, 1.5, True, "0.5", float("nan"), None):
        with pytest.raises(ValueError, match=f"relative_weight must be a number in \\[0, 1\\], got {re.escape(repr(bad))}"):
            hp.check_hyper("emulator", EMU | {"relative_weight": bad})
    for key in ("linear_skip", "log_inputs"):
        for bad in (1, "true", None):
            with pytest.raises(ValueError, match=f"{key} must be true or false, got {re.escape(repr(bad))}"):
                hp.check_hyper("emulator", EMU | {key: bad})
        with pytest.raises(ValueError, match="unknown"):
            hp.check_hyper("flow", FLOW | {key: True})
    assert hp.check_hyper("emulator", EMU)["relative_weight"] == 0.0
    with pytest.raises(ValueError, match="unknown"):
        hp.check_hyper("encoder_decoder", ENCDEC | {"relative_weight": 0.5})
    for bad in (-1, 2.5, ENCDEC["epochs"] + 1):
        with pytest.raises(ValueError, match="kl_warmup_epochs"):
            hp.check_hyper("encoder_decoder", ENCDEC | {"kl_warmup_epochs": bad})
    for bad in (0, -1.0, True, "4", float("inf")):
        with pytest.raises(ValueError, match=f"logvar_max must be null or a number > 0, got {re.escape(repr(bad))}"):
            hp.check_hyper("encoder_decoder", ENCDEC | {"logvar_max": bad})
    assert hp.check_hyper("encoder_decoder", ENCDEC)["logvar_max"] is None
    for bad in ({"restarts": 0}, {"restarts": 2}, {"restarts": 2, "restart_epochs": ENCDEC["epochs"]},
                {"restarts": 2, "restart_epochs": 5, "eval_every": 2}):
        with pytest.raises(ValueError, match="restart"):
            hp.check_hyper("encoder_decoder", ENCDEC | bad)
    for bad in ({"restart_target": 0.1}, {"restart_target": 0.1, "max_restarts": 2} | RESTARTS,
                {"max_restarts": 6} | RESTARTS, {"restart_target": 0.0} | RESTARTS):
        with pytest.raises(ValueError, match="restart_target"):
            hp.check_hyper("encoder_decoder", ENCDEC | bad)
    assert hp.check_hyper("encoder_decoder", ENCDEC | SCREEN)["max_restarts"] == 6
    with pytest.raises(ValueError, match="unknown"):
        hp.check_hyper("emulator", EMU | {"restart_target": 0.1})
    h = hp.check_hyper("emulator", EMU)
    assert h["restarts"] == 1
    assert h["weight_decay"] == 0.0 and h["grad_clip"] == 0.0
    assert h["lr_schedule"] == "step" and h["eval_every"] == 1 and not h["keep_best"] and h["dtype"] == "float32"
    # the cosine schedule needs no step parameters
    cos = {k: v for k, v in EMU.items() if k not in ("lr_step", "lr_gamma")} | {"lr_schedule": "cosine"}
    assert hp.check_hyper("emulator", cos)["lr_schedule"] == "cosine"


def test_hyper_defaults_are_read_from_the_schema(tmp_path, monkeypatch):
    """The defaults are the schema's: values, types and key order as the model files record them;
    a default edited in the schema is the one training uses."""
    from cvsim6.workflow import config

    h = hp.check_hyper("encoder_decoder", ENCDEC)
    assert list(h) == ["weight_decay", "grad_clip", "lr_schedule", "lr_step", "lr_gamma", "warmup_epochs", "lr_final",
                       "eval_every", "keep_best", "dtype", "restarts", "restart_epochs", "reduction", "activation",
                       "reeval_target", "noisy_scaling", "kl_warmup_epochs", "restart_target", "max_restarts",
                       "logvar_max", "log_parameters",
                       "beta_prior", "latent_dim", "encoder_hidden", "encoder_layers", "decoder_hidden",
                       "decoder_layers", "beta_d", "beta_v", "beta_r", "epochs", "batch_size", "lr"]
    assert h["lr_step"] == 10 and h["reduction"] == "sum" and h["beta_prior"] == 0.0
    assert type(h["weight_decay"]) is float and type(h["warmup_epochs"]) is int
    edited = config.SCHEMA_PATH.read_text().replace(
        "weight_decay: {description: Adam L2 penalty (0 = off)., type: number, minimum: 0, default: 0.0}",
        "weight_decay: {description: Adam L2 penalty (0 = off)., type: number, minimum: 0, default: 2.5e-4}")
    assert edited != config.SCHEMA_PATH.read_text()
    (tmp_path / "schema.yaml").write_text(edited)
    monkeypatch.setattr(config, "SCHEMA_PATH", tmp_path / "schema.yaml")
    assert hp.check_hyper("flow", FLOW)["weight_decay"] == 1e-5  # given: kept
    assert hp.check_hyper("emulator", EMU)["weight_decay"] == 2.5e-4


def test_hyper_errors_name_the_stage_key_and_value():
    with pytest.raises(ValueError, match=re.escape("flow hyperparameters: missing [], unknown ['hiden', 'lr_decay']")):
        hp.check_hyper("flow", FLOW | {"hiden": 3, "lr_decay": 0.5})
    with pytest.raises(ValueError, match=re.escape("emulator hyperparameter batch_size must be an integer >= 2, got 1")):
        hp.check_hyper("emulator", EMU | {"batch_size": 1})
    with pytest.raises(ValueError, match=re.escape("flow hyperparameter lr_gamma must be null or a number in (0, 1], "
                                                   "got 1.5")):
        hp.check_hyper("flow", FLOW | {"lr_gamma": 1.5})
    with pytest.raises(ValueError, match=re.escape("emulator hyperparameter lr_schedule must be one of 'step', "
                                                   "'cosine', got 'linear'")):
        hp.check_hyper("emulator", EMU | {"lr_schedule": "linear"})
    # the rules that tie keys together
    with pytest.raises(ValueError, match=re.escape("emulator hyperparameter warmup_epochs must be below epochs (25), "
                                                   "got 25")):
        hp.check_hyper("emulator", EMU | {"lr_schedule": "cosine", "warmup_epochs": 25})
    with pytest.raises(ValueError, match=re.escape("encoder_decoder hyperparameter kl_warmup_epochs must be at most "
                                                   "epochs (25), got 26")):
        hp.check_hyper("encoder_decoder", ENCDEC | {"kl_warmup_epochs": 26})
    with pytest.raises(ValueError, match=re.escape("flow: lr_schedule 'step' needs lr_step and lr_gamma, got 20, None")):
        hp.check_hyper("flow", {k: v for k, v in FLOW.items() if k != "lr_gamma"})
    with pytest.raises(ValueError, match=re.escape("flow hyperparameter restart_epochs must be an integer in [1, epochs)"
                                                   " and a multiple of eval_every (4) when restarts > 1, got 6")):
        hp.check_hyper("flow", FLOW | {"restarts": 2, "restart_epochs": 6, "eval_every": 4})
    assert hp.check_hyper("flow", FLOW | {"restarts": 2, "restart_epochs": 8, "eval_every": 4})["restarts"] == 2


