"""rtfit.experiments"""
