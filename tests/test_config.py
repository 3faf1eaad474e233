"""The config files and their JSON schema (cvsim6.workflow.config)."""
from __future__ import annotations

import copy
from pathlib import Path

import pytest

from cvsim6.workflow.config import SCHEMA_PATH, ConfigError, find_schema, load_config, validate_config

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ["config.yaml", "paper.yaml", "smoke.yaml"]


@pytest.fixture
def default_config() -> dict:
    return load_config(ROOT / "config" / "config.yaml")


def test_schema_path_is_the_repository_schema():
    assert SCHEMA_PATH == ROOT / "workflow" / "schemas" / "config.schema.yaml"
    assert find_schema(ROOT / "config") == SCHEMA_PATH


@pytest.mark.parametrize("name", CONFIGS)
def test_shipped_configs_validate(name):
    cfg = load_config(ROOT / "config" / name)
    before = copy.deepcopy(cfg)
    validate_config(cfg)
    validate_config(cfg, schema_path=SCHEMA_PATH)
    assert cfg == before, "validation must not inject defaults"


def test_smoke_config_is_small_and_others_are_paper_sized():
    assert load_config(ROOT / "config" / "smoke.yaml")["simulator"]["steps_per_cycle"] == 200
    for name in ("config.yaml", "paper.yaml"):
        sim = load_config(ROOT / "config" / name)["simulator"]
        assert sim == {"steps_per_cycle": 600, "n_cycles": 12, "window_cycles": 3, "method": "batch"}


def test_ehr_source(default_config):
    ehr = default_config["ehr_data"]
    assert ehr["path"] is None
    assert ehr["url"].endswith("/EHR_dataset.csv")
    assert ehr["sha256"] == "5beb040de24c2b6abad0963c002584957a7f422be084ccd7654c5c501b7e48ee"


def test_wrong_type_names_the_key(default_config):
    default_config["simulator"]["steps_per_cycle"] = "abc"
    with pytest.raises(ConfigError) as err:
        validate_config(default_config)
    assert "simulator.steps_per_cycle" in str(err.value)
    assert "'abc' is not of type 'integer'" in str(err.value)


def test_out_of_range_and_bad_enum_name_the_keys(default_config):
    default_config["seed"] = -1
    default_config["simulator"]["method"] = "euler"
    with pytest.raises(ConfigError) as err:
        validate_config(default_config)
    assert "seed:" in str(err.value)
    assert "simulator.method:" in str(err.value)


@pytest.mark.parametrize("section", [None, "simulator", "ehr_data"])
def test_unknown_key_is_named(default_config, section):
    target = default_config if section is None else default_config[section]
    target["foo"] = 1
    with pytest.raises(ConfigError) as err:
        validate_config(default_config)
    assert "'foo'" in str(err.value)
    if section is not None:
        assert f"unknown key 'foo' in {section}" in str(err.value)


def test_config_error_is_a_value_error():
    assert issubclass(ConfigError, ValueError)


def test_schema_documents_every_key_and_forbids_unknown_ones():
    import yaml

    schema = yaml.safe_load(SCHEMA_PATH.read_text())

    def walk(node, where):
        if node.get("type") == "object":  # unevaluatedProperties where keys come in through allOf/$ref
            assert node.get("additionalProperties") is False or node.get("unevaluatedProperties") is False, where
        for key, sub in node.get("properties", {}).items():
            assert sub.get("description"), f"{where}.{key} has no description"
            walk(sub, f"{where}.{key}")

    walk(schema, "<root>")
    for name, node in schema["$defs"].items():
        walk(node, f"$defs.{name}")


def test_empty_file_loads_as_empty_dict(tmp_path):
    p = tmp_path / "empty.yaml"
    p.write_text("")
    assert load_config(p) == {}


@pytest.mark.parametrize("name", CONFIGS)
def test_configs_merged_as_snakemake_does_give_valid_training_options(name):
    """``--configfile X`` is merged into config/config.yaml key by key (snakemake's
    update_config): a network entry must not inherit schedule options it did not state."""
    from snakemake.utils import update_config

    from cvsim6.training.hyperparameters import check_hyper

    cfg = load_config(ROOT / "config" / "config.yaml")
    update_config(cfg, load_config(ROOT / "config" / name))
    own = load_config(ROOT / "config" / name)["training"]["studies"]
    for study, nets in cfg["training"]["studies"].items():
        for net in ("emulator", "flow", "encoder_decoder"):
            h = check_hyper(net, nets[net])
            assert h["epochs"] == own[study][net]["epochs"]
            if name == "paper.yaml":  # the paper's step decay, evaluated every epoch, last weights
                assert (h["lr_schedule"], h["eval_every"], h["keep_best"]) == ("step", 1, False), (study, net)
                assert h["restarts"] == 1, (study, net)  # one initialization, as the paper
                assert (h["lr_step"], h["lr_gamma"]) == (own[study][net]["lr_step"], own[study][net]["lr_gamma"])
                if net == "emulator":  # the paper's plain MSE, every row weighing the same, and its MLP
                    assert h["variance_floor"] is None and h["relative_weight"] == 0, study
                    assert not h["linear_skip"] and not h["log_inputs"], study
                if net == "encoder_decoder":  # the paper's constant KL weight, one initialization,
                    # standardized parameters (not their logarithms), an uncapped log-variance
                    assert h["kl_warmup_epochs"] == 0 and h["restart_target"] is None, study
                    assert not h["log_parameters"] and h["logvar_max"] is None, study
                # a key not stated in paper.yaml comes from config.yaml: only those inert under the paper's
                # schedule (cosine warm-up, restart epochs) or the paper's code's own (the flow's clipping)
                inherited = set(nets[net]) - set(own[study][net])
                assert inherited <= {"warmup_epochs", "restart_epochs", "grad_clip"}, (study, net, inherited)


def test_training_hyperparameters_have_one_schema_entry_per_network():
    """The keys every network shares are written once ($defs/hyper_common) and taken in by each
    network's entry; every key has a description, every optional one a default."""
    import yaml

    from cvsim6.workflow.config import def_defaults, def_properties

    schema = yaml.safe_load(SCHEMA_PATH.read_text())
    common = schema["$defs"]["hyper_common"]["properties"]
    assert {"epochs", "batch_size", "lr", "lr_schedule", "restarts", "restart_epochs"} <= set(common)
    for net in ("emulator", "flow", "encoder_decoder"):
        node = schema["$defs"][f"{net}_hyper"]
        assert node["allOf"] == [{"$ref": "#/$defs/hyper_common"}] and node["unevaluatedProperties"] is False
        assert not set(common) & set(node["properties"]), net  # no shared key copied
        assert schema["$defs"]["training_study"]["properties"][net]["$ref"] == f"#/$defs/{net}_hyper"
        props, required = def_properties(f"{net}_hyper")
        assert list(props)[:len(common)] == list(common)
        assert all(p.get("description") for p in props.values()), net
        assert set(def_defaults(f"{net}_hyper")) == set(props) - set(required), net
    assert def_defaults("flow_hyper")["lr_schedule"] == "step" and def_defaults("flow_hyper")["lr_step"] is None


def test_unknown_training_key_is_named(default_config):
    default_config["training"]["studies"]["ehr"]["flow"]["hiden"] = 3
    with pytest.raises(ConfigError) as err:
        validate_config(default_config)
    assert str(err.value) == "unknown key 'hiden' in training.studies.ehr.flow"


@pytest.mark.parametrize("name", CONFIGS + ["published.yaml"])
def test_snakemake_validate_fills_the_defaults_check_hyper_fills(name):
    """Snakemake's validate (as the Snakefile calls it) accepts the merged config and fills in the
    schema's defaults: each network's hyperparameters then equal what training completes them to."""
    from snakemake.utils import update_config, validate

    from cvsim6.training.hyperparameters import check_hyper

    cfg = load_config(ROOT / "config" / "config.yaml")
    update_config(cfg, load_config(ROOT / "config" / name))
    written = copy.deepcopy(cfg)
    validate(cfg, str(SCHEMA_PATH))
    assert "restarts" not in written["training"]["studies"]["ehr"]["flow"]  # a default was filled in
    assert cfg["training"]["studies"]["ehr"]["flow"]["restarts"] == 1
    for study, nets in cfg["training"]["studies"].items():
        for net in ("emulator", "flow", "encoder_decoder"):
            assert nets[net] == check_hyper(net, written["training"]["studies"][study][net]), (study, net)
