"""Networks: the pretrained EfficientNet-Lite0 encoder and the backbone UNets built on it."""
