"""Guidance: the initial path, the loiter (orbit, NMPC with its CBF and solver process), the terminal BPNG and
scripted commands. CasADi loads only when the NMPC flies."""
