"""lodestar"""
