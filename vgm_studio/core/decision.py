"""When a p(success) says success."""

# A model says success at p(success) ≥ this unless a cut was chosen on validation edges, and a
# store without a model's own cut decides at it too. The one place the fallback is written.
DEFAULT_THRESHOLD = 0.5
