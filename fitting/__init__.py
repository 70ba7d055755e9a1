"""rtfit.fitting"""
