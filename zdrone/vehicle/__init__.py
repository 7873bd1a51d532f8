"""zdrone.vehicle"""
