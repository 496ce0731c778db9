"""Independent references (plain Python or numpy, from the formulas) that the product's laws
are tested against: never imported by the product."""
