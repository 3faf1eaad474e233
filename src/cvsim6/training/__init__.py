"""Resumable, seeded training of the three inVAErt stages (file-based, for Snakemake).

Modules: :mod:`~cvsim6.training.train` (the entry points, re-exported here),
:mod:`~cvsim6.training.hyperparameters` (``hyper`` checked and completed from the workflow
schema, which documents every key), :mod:`~cvsim6.training.stages` (emulator, flow and
encoder/decoder losses), :mod:`~cvsim6.training.loss_weights`,
:mod:`~cvsim6.training.optimization`, :mod:`~cvsim6.training.loop` (epochs, losses CSV,
checkpoints), :mod:`~cvsim6.training.restarts` (best of k initializations) and
:mod:`~cvsim6.training.fingerprint` (a run's identity).
"""
from cvsim6.training.train import train_emulator, train_encoder_decoder, train_flow

__all__ = ["train_emulator", "train_encoder_decoder", "train_flow"]
