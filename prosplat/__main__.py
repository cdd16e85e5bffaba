from prosplat.cli import main

main()
