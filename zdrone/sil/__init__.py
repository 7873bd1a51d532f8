"""zdrone.sil"""
