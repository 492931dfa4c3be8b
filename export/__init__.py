"""PyTorch side of svbrdf: renderer, data generation, networks, training, ONNX export.

May import :mod:`svbrdf_cli` (for the conventions); the runtime never imports this.
"""
