"""The camera-scene simulator: the paper's lab, rendered with ground truth."""
