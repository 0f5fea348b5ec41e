"""sewtol: tolerance and design-sensitivity analysis of sewing-machine mechanisms."""

__version__ = "0.1.0"
