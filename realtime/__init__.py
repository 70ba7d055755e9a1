"""rtfit.realtime"""
