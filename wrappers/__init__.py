"""Safety wrappers for the environments (the RCBF-QP shield arrives with the shield issue)."""
