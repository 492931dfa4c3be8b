"""Differentiable rendering and the paper's intermediate targets."""
