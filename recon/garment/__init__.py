"""Garments (thesis ch. 3 and 5): procedural outfit templates on the rest body (templates),
PBNS neural simulation (pbns, losses, train, evaluate), dressing a posed body of any shape
(dress) and animated glTF export (gltf)."""
