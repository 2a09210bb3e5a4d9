"""Moving (head-mounted) sensors: report B's measure, mutual capture, depth re-projection."""
