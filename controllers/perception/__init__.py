"""Perception: a detection made into a corrected fix and a decision (perception), with the ship-class model
that corrects the box centre and the own airframe's cut of the view (airframe)."""
