"""zdrone.net"""
