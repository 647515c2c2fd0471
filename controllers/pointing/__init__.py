"""Pointing: the gimbal's search raster, tracking law (IBVS) and reacquisition."""
