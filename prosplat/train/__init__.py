"""Training scripts (stage 1 generator; stage 2 and joint training come with issue 5)."""
