"""Baseline policies and training (the reference policy arrives with the shield issue)."""
