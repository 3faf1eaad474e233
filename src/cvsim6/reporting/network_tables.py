"""The paper's appendix-B tables (network architectures and training schedules) for the
config in use, with the parameter counts of the networks built from it beside the paper's."""
from __future__ import annotations

import pandas as pd

from cvsim6 import nets as nw
from cvsim6.paper_values import PARAMETER_COUNTS
from cvsim6.table_files import write_table


def network_tables(training: dict, study: str) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The paper's appendix-B tables (architectures, schedules) for the config in use.

    Parameter counts are those of the networks built from the config, with the
    paper's counts beside them.
    """
    cfg = training["studies"][study]
    e, f, d = cfg["emulator"], cfg["flow"], cfg["encoder_decoder"]
    ed = nw.EncoderDecoder(latent_dim=d["latent_dim"], encoder_hidden=d["encoder_hidden"],
                           encoder_layers=d["encoder_layers"], decoder_hidden=d["decoder_hidden"],
                           decoder_layers=d["decoder_layers"])
    counts = {
        "NN_e": nw.count_parameters(nw.Emulator(e["hidden"], e["layers"], linear_skip=e.get("linear_skip", False))),
        "NN_v": nw.count_parameters(ed.encoder),
        "NN_d": nw.count_parameters(ed.decoder),
        "NN_f": nw.count_parameters(nw.RealNVP(hidden=f["hidden"], blocks=f["blocks"],
                                               layers_per_block=f["layers_per_block"],
                                               batchnorm=bool(f["batchnorm"]))),
    }
    emulator_inputs = ("logs of the positive parameters, standardized" if e.get("log_inputs", False)
                       else "parameters, standardized")
    logp = d.get("log_parameters", False)
    encoder_inputs = "logs of the positive parameters, standardized" if logp else "parameters, standardized"
    decoder_outputs = " (gives the logs of the positive parameters)" if logp else ""
    arch = pd.DataFrame([
        {"Module": "NN_e", "Inputs": emulator_inputs, "Hidden units": e["hidden"], "Layers": e["layers"], "Blocks": "",
         "Activation": "SiLU" + (" + linear skip" if e.get("linear_skip", False) else ""), "BatchNorm": "",
         "Parameters": counts["NN_e"]},
        {"Module": "NN_v", "Inputs": encoder_inputs, "Hidden units": d["encoder_hidden"], "Layers": d["encoder_layers"], "Blocks": "",
         "Activation": "SiLU", "BatchNorm": "", "Parameters": counts["NN_v"]},
        {"Module": "NN_d", "Inputs": "outputs, standardized, and latent w" + decoder_outputs, "Hidden units": d["decoder_hidden"], "Layers": d["decoder_layers"], "Blocks": "",
         "Activation": "SiLU", "BatchNorm": "", "Parameters": counts["NN_d"]},
        {"Module": "NN_f", "Inputs": "outputs, standardized", "Hidden units": f["hidden"], "Layers": f["layers_per_block"], "Blocks": f["blocks"],
         "Activation": "Tanh (scale), ReLU (translation)", "BatchNorm": bool(f["batchnorm"]),
         "Parameters": counts["NN_f"]},
    ])
    arch["Parameters (paper)"] = [PARAMETER_COUNTS[study][m] for m in arch["Module"]]
    rows = []
    for name, h in (("NN_e", e), ("NN_f", f), ("NN_v + NN_d", d)):
        cosine = h.get("lr_schedule", "step") == "cosine"
        schedule = (f"cosine to {h.get('lr_final', 0.0):g} x lr, {h.get('warmup_epochs', 0)} warm-up epochs"
                    if cosine else f"x {h['lr_gamma']:g} every {h['lr_step']} epochs")
        if h.get("variance_floor") is not None:
            schedule += f"; loss with the output variances floored at {h['variance_floor']:g}"
        if h.get("kl_warmup_epochs"):
            k = h["kl_warmup_epochs"]
            schedule += f"; KL weight ramped up over the first {k} epoch{'s' if k != 1 else ''}"
        if h.get("beta_prior"):
            schedule += f"; re-evaluation also at prior draws w ~ N(0, I), weight {h['beta_prior']:g}"
        rows.append({"Module": name, "Minibatch": h["batch_size"], "Initial lr": h["lr"],
                     "Epochs": h["epochs"], "Schedule": schedule,
                     "Weight decay": h.get("weight_decay", 0.0)})
    sched = pd.DataFrame(rows)
    return arch, sched


_REDUCTION_WORDS = {"sum": "per-sample sums", "mse": "means over components"}


def write_network_tables(training: dict, study: str, architecture_csv: str, architecture_md: str,
                         schedule_csv: str, schedule_md: str) -> None:
    """Write the architecture and schedule tables of ``study`` (CSV + Markdown)."""
    arch, sched = network_tables(training, study)
    d = training["studies"][study]["encoder_decoder"]
    write_table(arch, architecture_csv, architecture_md,
                caption=f"inVAErt modules, {study} study (config in use; paper counts beside)")
    write_table(sched, schedule_csv, schedule_md,
                caption=f"Training schedules, {study} study (config in use). [beta_d, beta_v, beta_r] = "
                        f"[{d['beta_d']}, {d['beta_v']}, {d['beta_r']}] on the decoder, KL and re-evaluation terms "
                        f"(squared errors as {_REDUCTION_WORDS[d.get('reduction', 'sum')]}), dim(w) = {d['latent_dim']}, "
                        f"noise levels {training['studies'][study]['noise_levels']}")
