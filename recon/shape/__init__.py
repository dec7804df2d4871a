"""Body shape from the image: ``ShapeHead`` reads anny's phenotypes from the person's mask."""
from recon.shape.head import PHENOTYPES, WEIGHTS, ShapeHead, ShapeHeadConfig, crop_box, crop_mask

# The phenotypes the pipeline takes from the head rather than from SMPLR (chosen on synth-val).
FROM_MASK = ("gender", "muscle", "weight", "proportions")

__all__ = ["FROM_MASK", "PHENOTYPES", "WEIGHTS", "ShapeHead", "ShapeHeadConfig", "crop_box", "crop_mask"]
