from cevm.cli import main

main()
