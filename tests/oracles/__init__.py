"""Independent references (plain Python, from the formulas) that the product's laws are
tested against."""
