"""Benchmark: train the EHR study's noise-level copies of a network as one batched model?

The EHR study trains one flow and one encoder/decoder per noise level (four of each), all of
the same architecture. Batched, the copies' weights are stacked (G, in, out) and each layer is
one ``torch.baddbmm`` over the copies, so one optimizer step serves all of them. This script
times, one thread, the optimizer step (forward, backward, fused Adam with the config's weight
decay) of

* the copies as the workflow trains them: G separate package networks
  (:class:`cvsim6.nets.RealNVP`, :class:`cvsim6.nets.EncoderDecoder` with the
  re-evaluation term through an emulator of the study's architecture), one step each, and
* one batched model holding the same G copies' weights,

at the config's batch sizes, interleaved repeats, and prints ms per step of all G copies, the
ratio, and the CPU seconds that batching would save over the config's schedule. Before
timing it checks that the batched model computes each copy's loss as its own network does (the
comparison is like with like). A measurement only: the workflow does not batch the copies.

    .venv/bin/python benchmarks/batched_copies.py
    .venv/bin/python benchmarks/batched_copies.py --configfile config/paper.yaml --repeats 5

Writes ``benchmarks/results/batched_copies.json`` (``batched_copies_<config>_<study>.json`` for
another config file or study).
"""
from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import torch
import yaml
from torch import nn

from cvsim6 import nets as nw
from cvsim6.training.optimization import make_optimizer

ROOT = Path(__file__).resolve().parents[1]


class GroupedLinear(nn.Module):
    """G stacked ``nn.Linear`` layers: (G, N, in) -> (G, N, out), one ``baddbmm``."""

    def __init__(self, layers: list[nn.Linear]):
        super().__init__()
        self.weight = nn.Parameter(torch.stack([l.weight.detach().t() for l in layers]).contiguous())
        self.bias = nn.Parameter(torch.stack([l.bias.detach() for l in layers])[:, None, :].contiguous())

    def forward(self, x):
        return torch.baddbmm(self.bias, x, self.weight)


def grouped_mlp(mlps: list[nn.Sequential]) -> nn.Sequential:
    """The G MLPs as one: Linear layers stacked, activations shared."""
    return nn.Sequential(*[GroupedLinear(list(ls)) if isinstance(ls[0], nn.Linear) else ls[0].__class__()
                           for ls in zip(*mlps)])


class GroupedFlow(nn.Module):
    """G copies of a :class:`cvsim6.nets.RealNVP` (train-mode forward, data -> latent)."""

    def __init__(self, flows: list[nw.RealNVP]):
        super().__init__()
        self.dim = flows[0].dim
        self.layers = nn.ModuleList()
        self.kinds: list[tuple] = []
        for ls in zip(*[f.layers for f in flows]):
            if isinstance(ls[0], nw.AffineCoupling):
                m = nn.ModuleDict({"s": grouped_mlp([l.s for l in ls]), "t": grouped_mlp([l.t for l in ls])})
                self.kinds.append(("coupling", ls[0].d, ls[0].swap))
            else:
                m = nn.Module()
                m.log_gamma = nn.Parameter(torch.stack([l.log_gamma.detach() for l in ls])[:, None, :].clone())
                m.beta = nn.Parameter(torch.stack([l.beta.detach() for l in ls])[:, None, :].clone())
                m.register_buffer("running_mean", torch.stack([l.running_mean for l in ls])[:, None, :].clone())
                m.register_buffer("running_var", torch.stack([l.running_var for l in ls])[:, None, :].clone())
                self.kinds.append(("batchnorm", ls[0].momentum, ls[0].eps))
            self.layers.append(m)

    def nll(self, y):
        """Mean negative log-likelihood per copy, (G,), for standardized y (G, N, dim)."""
        z, logdet = y, y.new_zeros(y.shape[:2])
        for m, kind in zip(self.layers, self.kinds):
            if kind[0] == "coupling":
                d, swap = kind[1], kind[2]
                a, b = z[..., :d], z[..., d:]
                cond, trans = (b, a) if swap else (a, b)
                s = m["s"](cond)
                trans = trans * torch.exp(s) + m["t"](cond)
                z = torch.cat((trans, cond) if swap else (cond, trans), dim=-1)
                logdet = logdet + s.sum(dim=-1)
            else:
                momentum, eps = kind[1], kind[2]
                mean, var = z.mean(dim=-2, keepdim=True), z.var(dim=-2, unbiased=False, keepdim=True)
                with torch.no_grad():
                    n = z.shape[-2]
                    m.running_mean.lerp_(mean, momentum)
                    m.running_var.lerp_(var * (n / (n - 1)), momentum)
                z = torch.exp(m.log_gamma) * (z - mean) / torch.sqrt(var + eps) + m.beta
                logdet = logdet + (m.log_gamma - 0.5 * torch.log(var + eps)).sum(dim=-1)
        base = -0.5 * (z * z).sum(dim=-1) - 0.5 * self.dim * math.log(2.0 * math.pi)
        return -(base + logdet).mean(dim=-1)


class GroupedEncoderDecoder(nn.Module):
    """G copies of a :class:`cvsim6.nets.EncoderDecoder`."""

    def __init__(self, models: list[nw.EncoderDecoder]):
        super().__init__()
        self.latent = models[0].latent_dim
        self.encoder = grouped_mlp([m.encoder for m in models])
        self.decoder = grouped_mlp([m.decoder for m in models])

    def loss(self, v, y, eps, emulator, beta_d, beta_v, beta_r):
        """Per copy (G,): the package's loss with ``reduction="mse"`` (inputs (G, N, .))."""
        h = self.encoder(v)
        mu, logvar = h[..., : self.latent], h[..., self.latent:]
        v_hat = self.decoder(torch.cat((y, mu + eps * torch.exp(0.5 * logvar)), dim=-1))
        dec = ((v_hat - v) ** 2).mean(dim=(-2, -1))
        kl = 0.5 * (mu * mu + torch.exp(logvar) - logvar - 1.0).sum(dim=-1).mean(dim=-1)
        rec = ((emulator(v_hat) - y) ** 2).mean(dim=(-2, -1))
        return beta_d * dec + beta_v * kl + beta_r * rec


def _time(step, repeats: int, steps: int) -> list[float]:
    """Seconds per call of ``step``, one entry per repeat (after 3 warm-up calls)."""
    for _ in range(3):
        step()
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(steps):
            step()
        out.append((time.perf_counter() - t0) / steps)
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--configfile", default=str(ROOT / "config" / "config.yaml"))
    ap.add_argument("--study", default="ehr")
    ap.add_argument("--repeats", type=int, default=3, help="timed repeats of each side, interleaved")
    ap.add_argument("--steps", type=int, default=20, help="optimizer steps per repeat")
    import results_io

    results_io.add_note_argument(ap)
    args = ap.parse_args(argv)
    run = results_io.Run(None if argv is None else ["benchmarks/batched_copies.py", *argv])
    rows = []
    torch.set_num_threads(1)
    cfg = yaml.safe_load(open(args.configfile))
    split = cfg["data"]["studies"][args.study]["split"]
    n_train = round((cfg["data"]["studies"][args.study]["n_samples"] - split["validation"]) * split["train_fraction"])
    tr = cfg["training"]["studies"][args.study]
    g = len(tr["noise_levels"])
    gen = torch.Generator().manual_seed(0)
    emu_h = tr["emulator"]
    emulator = nw.Emulator(emu_h["hidden"], emu_h["layers"], activation=emu_h.get("activation", "silu"))
    emulator.requires_grad_(False)
    print(f"{args.study}: {g} noise-level copies, one thread, {n_train} training rows; ms per optimizer step of "
          f"all {g} copies (median of {args.repeats} x {args.steps} steps)")
    print("| network | batch | separate (ms) | batched (ms) | ratio | max rel. loss difference | "
          "CPU-s saved over the schedule |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for network in ("flow", "encoder_decoder"):
        h = tr[network]
        bs = int(h["batch_size"])
        torch.manual_seed(1)
        if network == "flow":
            nets = [nw.RealNVP(hidden=h["hidden"], blocks=h["blocks"], layers_per_block=h["layers_per_block"],
                               batchnorm=bool(h["batchnorm"])) for _ in range(g)]
            grouped = GroupedFlow(nets)
            ys = torch.randn(g, bs, nets[0].dim, generator=gen)

            def single_loss(k):
                return nw.flow_nll(nets[k], ys[k])

            def grouped_loss():
                return grouped.nll(ys)
        else:
            nets = [nw.EncoderDecoder(latent_dim=h["latent_dim"], encoder_hidden=h["encoder_hidden"],
                                      encoder_layers=h["encoder_layers"], decoder_hidden=h["decoder_hidden"],
                                      decoder_layers=h["decoder_layers"]) for _ in range(g)]
            grouped = GroupedEncoderDecoder(nets)
            vs = torch.randn(g, bs, 23, generator=gen)
            ys = torch.randn(g, bs, 16, generator=gen)
            es = torch.randn(g, bs, h["latent_dim"], generator=gen)
            betas = (float(h["beta_d"]), float(h["beta_v"]), float(h["beta_r"]))

            def single_loss(k):
                return nw.encoder_decoder_loss(nets[k], vs[k], ys[k], es[k], emulator, *betas, reduction="mse")[0]

            def grouped_loss():
                return grouped.loss(vs, ys, es, emulator, *betas)
        with torch.no_grad():  # like with like: the same losses at the same weights
            ref = torch.stack([single_loss(k) for k in range(g)])
            diff = float(((grouped_loss() - ref).abs() / ref.abs()).max())
        if diff > 1e-4:
            raise AssertionError(f"{network}: the batched model's losses differ from the copies' by {diff:.3g}")
        wd = float(h.get("weight_decay", 0.0))
        opts = [make_optimizer(n.parameters(), 1e-4, wd, torch.device("cpu")) for n in nets]
        gopt = make_optimizer(grouped.parameters(), 1e-4, wd, torch.device("cpu"))

        def separate_step():
            for k in range(g):
                opts[k].zero_grad(set_to_none=True)
                single_loss(k).backward()
                opts[k].step()

        def batched_step():
            gopt.zero_grad(set_to_none=True)
            grouped_loss().sum().backward()
            gopt.step()

        sep, bat = [], []
        for _ in range(args.repeats):
            sep += _time(separate_step, 1, args.steps)
            bat += _time(batched_step, 1, args.steps)
        s, b = sorted(sep)[len(sep) // 2], sorted(bat)[len(bat) // 2]
        steps_total = int(h["epochs"]) * (n_train // bs)
        print(f"| {network} | {bs} | {s * 1e3:.1f} | {b * 1e3:.1f} | {s / b:.2f} | {diff:.1e} | "
              f"{(s - b) * steps_total:.0f} of {s * steps_total:.0f} |")
        rows.append({"network": network, "copies": g, "batch_size": bs, "separate_ms": s * 1e3, "batched_ms": b * 1e3,
                     "speed_vs_separate": s / b, "max_rel_loss_difference": diff, "schedule_steps": steps_total,
                     "schedule_cpu_s_separate": s * steps_total, "schedule_cpu_s_saved": (s - b) * steps_total})
    import pandas as pd

    config = Path(args.configfile).resolve()
    default = config == (ROOT / "config" / "config.yaml").resolve() and args.study == "ehr"
    run.save(
        "batched_copies" if default else f"batched_copies_{config.stem}_{args.study}",
        f"Noise-level copies trained as one batched model ({args.study} study, {config.name})",
        f"The {args.study} study's noise-level copies of the flow and of the encoder/decoder: milliseconds per "
        f"optimizer step of all copies (median over the repeats, one thread), trained separately as the workflow "
        f"does against one batched model holding the same weights (checked to compute each copy's loss first); "
        f"the batched model's speed as a ratio to the separate copies' in the same run, and the CPU seconds "
        f"batching would save over the config's schedule. A measurement: the workflow does not batch the copies.",
        [results_io.table(pd.DataFrame(rows), "steps", "Per network: ms per optimizer step of all copies.",
                          {"separate_ms": ".3g", "batched_ms": ".3g", "speed_vs_separate": ".2f",
                           "max_rel_loss_difference": ".1e", "schedule_steps": ",d",
                           "schedule_cpu_s_separate": ",.0f", "schedule_cpu_s_saved": ",.0f"})],
        parameters={"configfile": config, "study": args.study, "repeats": args.repeats, "steps": args.steps,
                    "training_rows": n_train}, note=args.note)


if __name__ == "__main__":
    main()
